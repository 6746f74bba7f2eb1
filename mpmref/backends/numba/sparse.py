r"""The Numba backend's sparse grid: only the blocks that particles' stencils reach are stored.

This is the idea of SPGrid (Setaluri, Aanjaneya, Bauer & Sifakis 2014), which the talk's Part IV cites for
grids that follow the material: the domain is cut into blocks of :math:`B^d` nodes (the grid's ``block``,
:class:`mpmref.state.Grid`), a small **block-pointer table** over all blocks of the domain says which of
them are active and where each active block's nodes are stored, and the node values themselves live in
compact storage, block after block. A body that fills a small part of a large domain then costs what it
costs about what it costs in a tight domain: node storage, zeroing, the grid update and the output follow
the active blocks; only the table (4 bytes per block, :math:`(256/4 + 2)^3 \cdot 4` bytes = 1.1 MiB for
:math:`256^3` cells) and the sort's per-block counts (:mod:`.blocks`, 8 bytes per block) grow with the
domain, each set once per step.

**Which blocks are active.** A particle's owner block ``b`` (the block of its stencil's base node,
:mod:`.blocks`) receives its stencil, which spans nodes ``b_a B .. b_a B + B + S - 2`` per axis; with
``B >= S - 1`` these lie in blocks ``b_a`` and ``b_a + 1``. The active blocks are therefore every non-empty
owner block and its :math:`2^d - 1` upper neighbours, rebuilt every step from the sort. Nodes of an active
block that no stencil reaches have no mass and zero velocity, as they have on the dense grid; nodes outside
the active blocks are never read by G2P, so the sparse step gives the same bits as a dense one.

**Rows.** Active blocks get slots in C order of their block coordinates; node ``(i, j[, k])`` of the block
in slot ``s`` is row :math:`s B^d + \sum_a (i_a \bmod B) B^{d-1-a}` of the node arrays. The table has one
more block per axis than the grid (:attr:`BlockLayout.table_shape`), so the upper neighbour of any owner
block exists; blocks beyond the domain's last node hold only empty padding rows. The transfer kernels find the
rows of a particle's stencil with :func:`block_rows_2d` or :func:`block_rows_3d` (the first rows of the blocks
it spans) and, per axis, :func:`hops` and :func:`local_rows`.
"""

from functools import cached_property

import numpy as np
from numba import njit


class BlockLayout:
    """Active blocks of one step and the rows of their nodes (see the module doc).

    Attributes
    ----------
    block : int                    cells per block edge :math:`B`
    node_shape : (d,) int          nodes of the whole grid per axis
    table_shape : (d,) int         blocks per axis of the block-pointer table (the grid's plus one)
    slot_of : (prod(table_shape),) int32   slot of each block (C order of block coordinates), -1 if inactive
    blocks : (n_slots, d) int64    block coordinates of each slot, in C order
    """

    def __init__(self, block, node_shape, table_shape, slot_of, blocks):
        self.block, self.node_shape, self.table_shape = block, np.asarray(node_shape), table_shape
        self.slot_of, self.blocks = slot_of, blocks

    @classmethod
    def from_sort(cls, block_start, blocks_per_axis, block, node_shape):
        """The layout of the particles sorted by :func:`.blocks.counting_sort` (``block_start``)."""
        table_shape = np.asarray(blocks_per_axis, dtype=np.int64) + 1
        slot_of, blocks = active_blocks(block_start, np.asarray(blocks_per_axis, dtype=np.int64), table_shape)
        return cls(block, node_shape, table_shape, slot_of, blocks)

    @property
    def dim(self):
        return self.blocks.shape[1]

    @property
    def block_nodes(self):
        """Nodes per block, :math:`B^d`."""
        return self.block**self.dim

    @property
    def n_rows(self):
        """Rows of the node arrays: every node of every active block."""
        return self.blocks.shape[0] * self.block_nodes

    @cached_property
    def table_strides(self):
        """Linear-index strides of the block-pointer table."""
        t = self.table_shape
        return np.array([int(np.prod(t[a + 1:])) for a in range(len(t))], dtype=np.int64)

    @cached_property
    def node_index(self):
        """Integer multi-index (n_rows, d) of the node of every row (padding rows lie beyond ``node_shape``)."""
        d, B = self.dim, self.block
        local = np.stack(np.meshgrid(*[np.arange(B)] * d, indexing="ij"), axis=-1).reshape(-1, d)
        return (self.blocks[:, None, :] * B + local[None, :, :]).reshape(-1, d)

    @cached_property
    def inside(self):
        """Which rows are nodes of the grid (not padding beyond its last node), (n_rows,) bool."""
        return np.all(self.node_index < self.node_shape, axis=1)

    def dense_index(self):
        """C-order index in the dense node array of each row inside the grid (the rows of :attr:`inside`)."""
        index = self.node_index[self.inside]
        strides = np.array([int(np.prod(self.node_shape[a + 1:])) for a in range(self.dim)], dtype=np.int64)
        return index @ strides

    def to_dense(self, values):
        """Row values (n_rows, ...) scattered to a dense C-ordered node array (N, ...), zero elsewhere."""
        dense = np.zeros((int(np.prod(self.node_shape)),) + values.shape[1:], dtype=values.dtype)
        dense[self.dense_index()] = values[self.inside]
        return dense

    def from_dense(self, dense, out=None):
        """Dense C-ordered node values (N, ...) gathered into rows (``out`` or a new array; padding rows 0)."""
        if out is None:
            out = np.zeros((self.n_rows,) + dense.shape[1:], dtype=dense.dtype)
        out[self.inside] = dense[self.dense_index()]
        return out


#: table entry of a block found active whose slot is not yet assigned
MARKED = -2


@njit(cache=True)
def active_blocks(block_start, blocks_per_axis, table_shape):
    """The block-pointer table and the slots' block coordinates of the non-empty owner blocks of a sort
    (``block_start``, over the grid's ``blocks_per_axis``) and their upper neighbours (see the module doc).

    Returns ``(slot_of, blocks)``: ``slot_of`` (int32, one entry per block of ``table_shape``, C order) holds
    each active block's slot and -1 elsewhere; ``blocks[s]`` are the coordinates of slot ``s``'s block. Only
    the slabs (blocks sharing their first coordinate) that hold particles, and the table's slabs they mark,
    are scanned: the work follows the body, bar one pass over the slabs and the table's initialisation.
    """
    d = blocks_per_axis.shape[0]
    per_slab, table_per_slab = 1, 1
    for a in range(1, d):
        per_slab *= blocks_per_axis[a]
        table_per_slab *= table_shape[a]
    slot_of = np.full(table_shape[0] * table_per_slab, -1, dtype=np.int32)
    marked_slab = np.zeros(table_shape[0], dtype=np.bool_)
    coords = np.empty(d, dtype=np.int64)
    for slab in range(blocks_per_axis[0]):
        if block_start[(slab + 1) * per_slab] == block_start[slab * per_slab]:
            continue
        marked_slab[slab] = marked_slab[slab + 1] = True
        for b in range(slab * per_slab, (slab + 1) * per_slab):
            if block_start[b + 1] == block_start[b]:
                continue
            rest = b
            for a in range(d - 1, -1, -1):
                coords[a] = rest % blocks_per_axis[a]
                rest //= blocks_per_axis[a]
            for corner in range(2**d):
                t = 0
                for a in range(d):
                    t = t * table_shape[a] + coords[a] + ((corner >> (d - 1 - a)) & 1)
                slot_of[t] = MARKED
    n_slots = 0
    for slab in range(table_shape[0]):
        if marked_slab[slab]:
            for t in range(slab * table_per_slab, (slab + 1) * table_per_slab):
                n_slots += slot_of[t] == MARKED
    blocks = np.empty((n_slots, d), dtype=np.int64)
    slot = 0
    for slab in range(table_shape[0]):
        if not marked_slab[slab]:
            continue
        for t in range(slab * table_per_slab, (slab + 1) * table_per_slab):
            if slot_of[t] == MARKED:
                slot_of[t] = slot
                rest = t
                for a in range(d - 1, -1, -1):
                    blocks[slot, a] = rest % table_shape[a]
                    rest //= table_shape[a]
                slot += 1
    return slot_of, blocks


@njit(cache=True, inline="always")
def hops(local_base, block, S):
    """Per stencil node ``k = 0 .. S-1`` of one axis whose base node lies ``local_base`` nodes into its block:
    whether node ``k`` lies in the next block along the axis (a tuple of bools)."""
    if S == 2:
        return (local_base >= block, local_base + 1 >= block)
    if S == 3:
        return (local_base >= block, local_base + 1 >= block, local_base + 2 >= block)
    return (local_base >= block, local_base + 1 >= block, local_base + 2 >= block, local_base + 3 >= block)


@njit(cache=True, inline="always")
def local_rows(local_base, block, row_stride, next_block, S):
    """Per stencil node of one axis (a tuple of ``S``): its index within its block times ``row_stride`` (the
    block's row stride along the axis, :math:`B^{d-1-a}`), plus ``next_block`` for a node in the next block."""
    if S == 2:
        return (node_row(local_base, block, row_stride, next_block),
                node_row(local_base + 1, block, row_stride, next_block))
    if S == 3:
        return (node_row(local_base, block, row_stride, next_block),
                node_row(local_base + 1, block, row_stride, next_block),
                node_row(local_base + 2, block, row_stride, next_block))
    return (node_row(local_base, block, row_stride, next_block),
            node_row(local_base + 1, block, row_stride, next_block),
            node_row(local_base + 2, block, row_stride, next_block),
            node_row(local_base + 3, block, row_stride, next_block))


@njit(cache=True, inline="always")
def node_row(local, block, row_stride, next_block):
    """Row offset of a node ``local`` nodes past the start of its owner block (at most ``2 block - 1``)."""
    if local >= block:
        return (local - block) * row_stride + next_block
    return local * row_stride


@njit(cache=True, inline="always")
def block_rows_2d(b0, b1, slot_of, table_strides, block):
    r"""First rows of the owner block of a 2D stencil with base node ``(b0, b1)`` and of its upper neighbour
    along axis 0 (look-ups in the block-pointer table ``slot_of``; see the module doc, "Rows").

    With per axis :func:`hops` and :func:`local_rows`, node ``(i, j)`` of the stencil is row
    ``(k1 if hop0[i] else k0) + r0[i] + r1[j]``: the upper neighbour along the last axis needs no look-up, as it
    is the next slot (:math:`B^d` rows on) in C order of the blocks, so ``r1`` holds that step.
    """
    n = block * block
    t = b0 // block * table_strides[0] + b1 // block * table_strides[1]
    return slot_of[t] * n, slot_of[t + table_strides[0]] * n


@njit(cache=True, inline="always")
def block_rows_3d(b0, b1, b2, slot_of, table_strides, block):
    r"""First rows of the owner block of a 3D stencil with base node ``(b0, b1, b2)`` and of its upper neighbours
    along axes 0 and 1 (``k10`` one block up along axis 0); node ``(i, j, l)`` is row
    ``k[hop0[i]][hop1[j]] + r0[i] + r1[j] + r2[l]`` (see :func:`block_rows_2d`)."""
    n = block * block * block
    s0, s1 = table_strides[0], table_strides[1]
    t = b0 // block * s0 + b1 // block * s1 + b2 // block * table_strides[2]
    return slot_of[t] * n, slot_of[t + s1] * n, slot_of[t + s0] * n, slot_of[t + s0 + s1] * n


r"""Sorting particles into blocks of cells, and the colouring that makes parallel P2G race-free.

A particle belongs to the block that holds its stencil's base node: block coordinate
``b_a = base_a // B`` per axis (``B`` = the grid's ``block`` cells, :class:`mpmref.state.Grid`). The particles of one block write only to
nodes ``b_a B .. b_a B + B + S - 2`` per axis (``S`` the kernel support), so two blocks whose coordinates
differ by at least 2 on some axis never write the same node when ``B >= S - 1``. Colouring blocks by the
parities of their coordinates (:math:`2^d` colours) therefore gives colour classes whose blocks can
scatter concurrently without atomics (the talk's Part IV motivates blocked transfers for locality; the
parity colouring is this toolkit's way of running them in parallel without atomics or private grids).

Inside a block particles keep their original order (a stable counting sort). Each node therefore
receives its contributions in a fixed order — colour by colour, then particle by particle within the
one block of that colour that reaches it — independent of how many threads run: P2G is bitwise the same
for any thread count.
"""

import numpy as np
from numba import njit, prange

@njit(parallel=True, cache=True)
def sort_into_blocks(x, origin, dx, shift, block, blocks_per_axis):
    """Stable counting sort of particles by block, and the non-empty blocks grouped by colour.

    The block of each particle is computed in parallel; the counts and the stable placement are one serial
    pass each (their order is what makes the sort stable).

    Parameters
    ----------
    x : (n, d)                 particle positions
    origin : (d,), dx : float  the grid
    shift : float              ``base = floor((x - origin)/dx - shift)`` (the kernel's base-node rule)
    block : int                cells per block edge
    blocks_per_axis : (d,) int

    Returns
    -------
    order : (n,) int           particle indices, block by block
    block_start : (n_blocks + 1,) int   ``order[block_start[b]:block_start[b+1]]`` are block ``b``'s particles
    colour_blocks : (k,) int   the non-empty blocks, colour 0 first
    colour_start : (2**d + 1,) int      ``colour_blocks[colour_start[c]:colour_start[c+1]]`` have colour ``c``
    """
    n, d = x.shape
    n_blocks = 1
    for a in range(d):
        n_blocks *= blocks_per_axis[a]
    block_of = np.empty(n, dtype=np.int64)
    for p in prange(n):
        b = 0
        for a in range(d):
            base = int(np.floor((x[p, a] - origin[a]) / dx - shift))
            b = b * blocks_per_axis[a] + base // block
        block_of[p] = b
    counts = np.zeros(n_blocks + 1, dtype=np.int64)
    for p in range(n):
        counts[block_of[p] + 1] += 1
    block_start = np.cumsum(counts)
    fill = block_start[:-1].copy()
    order = np.empty(n, dtype=np.int64)
    for p in range(n):
        order[fill[block_of[p]]] = p
        fill[block_of[p]] += 1
    return order, block_start, *colour_classes(block_start, blocks_per_axis)


@njit(cache=True)
def colour_classes(block_start, blocks_per_axis):
    """Non-empty blocks grouped by colour ``sum_a (b_a mod 2) 2^a``; see :func:`sort_into_blocks`."""
    d = blocks_per_axis.shape[0]
    n_colours = 2**d
    n_blocks = block_start.shape[0] - 1
    colour = np.empty(n_blocks, dtype=np.int64)
    per_colour = np.zeros(n_colours + 1, dtype=np.int64)
    for b in range(n_blocks):
        rest, c = b, 0
        for a in range(d - 1, -1, -1):
            c += (rest % blocks_per_axis[a]) % 2 * 2**a
            rest //= blocks_per_axis[a]
        colour[b] = c
        if block_start[b + 1] > block_start[b]:
            per_colour[c + 1] += 1
    colour_start = np.cumsum(per_colour)
    fill = colour_start[:-1].copy()
    colour_blocks = np.empty(colour_start[-1], dtype=np.int64)
    for b in range(n_blocks):
        if block_start[b + 1] > block_start[b]:
            colour_blocks[fill[colour[b]]] = b
            fill[colour[b]] += 1
    return colour_blocks, colour_start

r"""Sorting particles into blocks of cells, and the two-colour slabs that make parallel P2G race-free.

A particle belongs to the block that holds its stencil's base node: block coordinate
``b_a = base_a // B`` per axis (``B`` = the grid's ``block`` cells, :class:`mpmref.state.Grid`). The particles
of one block write only to nodes ``b_a B .. b_a B + B + S - 2`` per axis (``S`` the kernel support). Blocks
are numbered in C order, so the blocks that share their first coordinate ``b_0`` — a **slab** one block
thick — are consecutive, and after the sort their particles are one contiguous run of ``order``. Two slabs
whose ``b_0`` differ by at least 2 never write the same node when ``B >= S - 1``. Colouring slabs by the
parity of ``b_0`` therefore gives two colour classes whose slabs can scatter concurrently without atomics,
in two parallel passes whatever the dimension (the talk's Part IV motivates blocked transfers for
locality; the parity colouring is this toolkit's way of running them in parallel without atomics or
private grids). Where a body spans too few slabs to share among the threads, single blocks coloured by
the parities of all their coordinates (:func:`colour_classes`, :math:`2^d` colours) take their place.

Inside a block particles keep their original order (a stable counting sort). Each node therefore
receives its contributions in a fixed order — colour by colour, then particle by particle within the
one slab of that colour that reaches it — independent of how many threads run: P2G is bitwise the same
for any thread count.
"""

import numpy as np
from numba import njit, prange

from .twin import parallel_kernel


@parallel_kernel(cache=True)
def block_keys(x, rows, origin, dx, shift, block, blocks_per_axis):
    """The block (C-order number) of each particle: the block of its stencil's base node, in parallel; of every
    particle when ``rows`` is empty, else of the particles ``rows`` (the ``k``-th key that of ``rows[k]``).

    Parameters
    ----------
    x : (n, d)                 particle positions
    rows : (m,) int            the particles to key (empty: all)
    origin : (d,), dx : float  the grid
    shift : float              ``base = floor((x - origin)/dx - shift)`` (the kernel's base-node rule)
    block : int                cells per block edge (a power of two)
    blocks_per_axis : (d,) int
    """
    d = x.shape[1]
    some = rows.shape[0] > 0
    n = rows.shape[0] if some else x.shape[0]
    bits = 0  # block is a power of two: a node's block coordinate is an arithmetic shift (a floor division)
    while (1 << bits) < block:
        bits += 1
    block_of = np.empty(n, dtype=np.int64)
    for k in prange(n):
        p = rows[k] if some else np.int64(k)  # one integer type (prange counts unsigned)
        b = 0
        for a in range(d):
            base = int(np.floor((x[p, a] - origin[a]) / dx - shift))
            b = b * blocks_per_axis[a] + (base >> bits)
        block_of[k] = b
    return block_of


@njit(cache=True)
def counting_sort(block_of, n_blocks):
    """Stable counting sort of particles by their block ``block_of``: ``(order, block_start)``, ``order`` the
    particle indices block by block and ``order[block_start[b]:block_start[b+1]]`` block ``b``'s particles.

    The counts and the stable placement are one serial pass each (their order is what makes the sort stable), so
    the result depends on ``block_of`` alone.
    """
    n = block_of.shape[0]
    block_start = np.zeros(n_blocks + 1, dtype=np.int64)  # counts first, then their running sum in place
    for p in range(n):
        block_start[block_of[p] + 1] += 1
    for b in range(n_blocks):
        block_start[b + 1] += block_start[b]
    fill = np.empty(n_blocks, dtype=np.int64)  # next free place of each block: touched for occupied blocks only
    for p in range(n):
        fill[block_of[p]] = block_start[block_of[p]]
    order = np.empty(n, dtype=np.int64)
    for p in range(n):
        order[fill[block_of[p]]] = p
        fill[block_of[p]] += 1
    return order, block_start


@njit(cache=True)
def slab_colours(block_start, blocks_per_axis):
    """``(slab_start, slabs, colour_start)`` of the slabs (see the module doc).

    ``order[slab_start[s]:slab_start[s+1]]`` are slab ``s``'s particles; ``slabs`` lists the non-empty
    slabs, colour 0 (even ``b_0``) first; ``slabs[colour_start[c]:colour_start[c+1]]`` have colour ``c``.
    """
    per_slab = (block_start.shape[0] - 1) // blocks_per_axis[0]
    n_slabs = blocks_per_axis[0]
    slab_start = np.empty(n_slabs + 1, dtype=np.int64)
    for s in range(n_slabs + 1):
        slab_start[s] = block_start[s * per_slab]
    slabs = np.empty(n_slabs, dtype=np.int64)
    count = 0
    for parity in range(2):
        for s in range(parity, n_slabs, 2):
            if slab_start[s + 1] > slab_start[s]:
                slabs[count] = s
                count += 1
        if parity == 0:
            even = count
    colour_start = np.array([0, even, count], dtype=np.int64)
    return slab_start, slabs[:count], colour_start


@njit(cache=True)
def occupied_blocks(block_start, blocks_per_axis):
    """The blocks that hold particles, in increasing block number. Only the slabs that hold particles are
    scanned, so the work follows the body, not the domain."""
    per_slab = (block_start.shape[0] - 1) // blocks_per_axis[0]
    out = np.empty(min(block_start[-1], block_start.shape[0] - 1), dtype=np.int64)  # at most one per particle
    count = 0
    for slab in range(blocks_per_axis[0]):
        if block_start[(slab + 1) * per_slab] == block_start[slab * per_slab]:
            continue
        for b in range(slab * per_slab, (slab + 1) * per_slab):
            if block_start[b + 1] > block_start[b]:
                out[count] = b
                count += 1
    return out[:count]


@njit(cache=True)
def colour_classes(block_start, blocks_per_axis):
    """Non-empty blocks grouped by the colour ``sum_a (b_a mod 2) 2^a`` of all their coordinates (:math:`2^d`
    colours; blocks of one colour never share a node when ``B >= S - 1``): ``(colour_blocks, colour_start)``,
    ``colour_blocks[colour_start[c]:colour_start[c+1]]`` having colour ``c``, in increasing block number. The
    CPIC kernels (:mod:`mpmref.backends.numba.cpic`), and P2G where slabs are few, run block by block in these
    classes."""
    d = blocks_per_axis.shape[0]
    blocks = occupied_blocks(block_start, blocks_per_axis)
    colour = np.empty(blocks.shape[0], dtype=np.int64)
    colour_start = np.zeros((1 << d) + 1, dtype=np.int64)
    for i in range(blocks.shape[0]):
        rest, c = blocks[i], 0
        for a in range(d - 1, -1, -1):
            c += (rest % blocks_per_axis[a]) % 2 << a
            rest //= blocks_per_axis[a]
        colour[i] = c
        colour_start[c + 1] += 1
    for c in range(1 << d):
        colour_start[c + 1] += colour_start[c]
    placed = colour_start[:-1].copy()  # a counting sort: stable, block order kept within a colour
    colour_blocks = np.empty_like(blocks)
    for i in range(blocks.shape[0]):
        colour_blocks[placed[colour[i]]] = blocks[i]
        placed[colour[i]] += 1
    return colour_blocks, colour_start


@njit(cache=True)
def runs_of(rows):
    """The runs of consecutive particles in ``rows`` (an index array): ``(starts, stops)``, run ``r`` being
    ``starts[r] .. stops[r] - 1``, in the order of ``rows``."""
    n_runs = 0
    for k in range(rows.shape[0]):
        if k == 0 or rows[k] != rows[k - 1] + 1:
            n_runs += 1
    starts = np.empty(n_runs, np.int64)
    stops = np.empty(n_runs, np.int64)
    r = -1
    for k in range(rows.shape[0]):
        if k == 0 or rows[k] != rows[k - 1] + 1:
            r += 1
            starts[r] = rows[k]
        stops[r] = rows[k] + 1
    return starts, stops

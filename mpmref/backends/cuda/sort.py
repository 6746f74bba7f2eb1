r"""The particles ordered by the node below them, the same order every run: a counting sort on the GPU.

P2G gathers (:mod:`mpmref.backends.cuda.p2g`): each node sums the particles of the cells whose stencil reaches it,
cell by cell, and within a cell in the order of :func:`sort_by_cell`. A particle's *cell* is its base node
:math:`b = \lfloor (x_p - o)/\Delta x - s\rfloor` (one index per axis, C order over the grid's nodes). The sort:

1. ``cell_keys``: each particle's cell, and its rank among the particles of that cell as an atomic counter gives it
   (integer atomics: the counts are exact, the ranks depend on the order in which threads arrive); and the box of
   cells that hold particles, so that P2G skips the nodes outside it at once;
2. an exclusive prefix sum of the counts: each cell's first slot (:func:`exclusive_scan`, a block-wise scan in shared
   memory, recursively over the blocks' totals: integer sums, exact whatever the order);
3. ``scatter``: each particle to its cell's first slot plus its rank;
4. ``order_cells``: each cell's particles put in increasing particle index (an insertion sort per cell, a handful of
   particles each), which removes the dependence on the threads' arrival.

So the order is a function of the positions alone: the sort is stable (ties in particle order), and a P2G that sums
in this order gives the same bits on every run. A particle whose stencil does not fit on the grid (outside the valid
region, which the run's domain check never lets a step start from) gets the key ``n_nodes``: it sorts after every
cell, and no node sums it.
"""

from functools import lru_cache

import numpy as np
from numba import types

from ...physics.kernels import KERNELS
from ..pointwise.stencil import KERNEL_CODES, fraction
from .launch import BLOCK, array, device, kernel_set, scalar
from .runtime import cuda, load

INDEX = np.int32
#: the lower corner of the empty box of cells (larger than any cell index)
NO_CELL = np.iinfo(np.int32).max


@lru_cache(maxsize=None)
def sort_kernels(dtype, dim, kernel):
    """The sort's kernels for particles of ``dtype`` in ``dim`` dimensions with the kernel named ``kernel``: a
    namespace of :class:`~.launch.DeviceKernel` ``cell_keys``, ``scatter``, ``order_cells``, ``reset``,
    ``scan_blocks`` and ``add_block_offsets``."""
    load()
    T = np.dtype(dtype).type
    KERNEL, S = KERNEL_CODES[kernel], KERNELS[kernel].support
    base_of = device(fraction)
    D = dim
    ints = array(INDEX, 1)

    def cell_keys(x, origin, dx, node_shape, keys, count, rank, box):
        """``keys[p]``: particle ``p``'s cell (``n_nodes`` where its stencil does not fit); ``rank[p]``: its arrival
        at the cell's counter ``count[keys[p]]``; ``box``: the smallest (first three) and largest (last three) cell
        index per axis of the particles that fit (a reduction in shared memory, then one atomic per block)."""
        low = cuda.shared.array((3, BLOCK), types.int32)
        high = cuda.shared.array((3, BLOCK), types.int32)
        t = cuda.threadIdx.x
        p = cuda.grid(1)
        for a in range(3):
            low[a, t] = NO_CELL
            high[a, t] = -1
        if p < x.shape[0]:
            key = 0
            fits = True
            for a in range(D):
                b = base_of(KERNEL, T, (x[p, a] - origin[a]) / T(dx))[0]
                fits = fits and 0 <= b and b + S <= node_shape[a]
                key = key * node_shape[a] + b
                low[a, t] = b
                high[a, t] = b
            if not fits:
                key = count.shape[0] - 1
                for a in range(D):
                    low[a, t] = NO_CELL
                    high[a, t] = -1
            keys[p] = key
            rank[p] = cuda.atomic.add(count, key, 1)
        cuda.syncthreads()
        step = BLOCK // 2
        while step > 0:
            if t < step:
                for a in range(D):
                    low[a, t] = min(low[a, t], low[a, t + step])
                    high[a, t] = max(high[a, t], high[a, t + step])
            cuda.syncthreads()
            step //= 2
        if t == 0:
            for a in range(D):
                cuda.atomic.min(box, a, low[a, 0])
                cuda.atomic.max(box, 3 + a, high[a, 0])

    def scatter(keys, rank, start, order):
        """``order[start[keys[p]] + rank[p]] = p``."""
        p = cuda.grid(1)
        if p < keys.shape[0]:
            order[start[keys[p]] + rank[p]] = p

    def order_cells(start, order):
        """The particles of cell ``c`` (``order[start[c]:start[c + 1]]``) put in increasing index."""
        c = cuda.grid(1)
        if c >= start.shape[0] - 1:
            return
        lo, hi = start[c], start[c + 1]
        for i in range(lo + 1, hi):
            p = order[i]
            j = i - 1
            while j >= lo and order[j] > p:
                order[j + 1] = order[j]
                j -= 1
            order[j + 1] = p

    def reset(count, box):
        """``count`` set to zero, ``box`` to the empty box (see ``cell_keys``)."""
        i = cuda.grid(1)
        if i < count.shape[0]:
            count[i] = 0
        if i < 3:
            box[i] = NO_CELL
            box[3 + i] = -1

    def scan_blocks(values, out, totals):
        """Exclusive prefix sums of ``values`` within each block of :data:`~.launch.BLOCK` entries into ``out``,
        each block's total into ``totals`` (Hillis & Steele 1986's scan in shared memory)."""
        shared = cuda.shared.array(BLOCK, types.int32)
        i = cuda.grid(1)
        t = cuda.threadIdx.x
        own = values[i] if i < values.shape[0] else 0
        shared[t] = own
        cuda.syncthreads()
        step = 1
        while step < BLOCK:
            add = shared[t - step] if t >= step else 0
            cuda.syncthreads()
            shared[t] += add
            cuda.syncthreads()
            step *= 2
        if i < values.shape[0]:
            out[i] = shared[t] - own
        if t == BLOCK - 1:
            totals[cuda.blockIdx.x] = shared[t]

    def add_block_offsets(out, offsets):
        """``out[i] += offsets[i // BLOCK]``: block-wise sums made global."""
        i = cuda.grid(1)
        if i < out.shape[0]:
            out[i] += offsets[i // BLOCK]

    x_type = array(dtype, 2)
    return kernel_set(
        cell_keys=(cell_keys, (x_type, array(dtype, 1), scalar(np.float64), array(np.int64, 1), ints, ints, ints,
                               ints)),
        scatter=(scatter, (ints, ints, ints, ints)),
        order_cells=(order_cells, (ints, ints)),
        reset=(reset, (ints, ints)),
        scan_blocks=(scan_blocks, (ints, ints, ints)),
        add_block_offsets=(add_block_offsets, (ints, ints)))


def exclusive_scan(kernels, values, out, scratch):
    """``out[i] = sum(values[:i])`` over the int32 device array ``values`` (same length), by blocks and recursively
    over the blocks' totals; ``scratch(kind, n)`` hands out int32 device arrays of ``n`` entries."""
    n = values.shape[0]
    blocks = (n + BLOCK - 1) // BLOCK
    totals = scratch(f"scan_totals_{n}", blocks)
    kernels.scan_blocks(n, values, out, totals)
    if blocks == 1:
        return out
    offsets = scratch(f"scan_offsets_{n}", blocks)
    exclusive_scan(kernels, totals, offsets, scratch)
    kernels.add_block_offsets(n, out, offsets)
    return out

"""Compiled bookkeeping of asynchronous stepping: row copies between particle stores, the ghost zone, the
ghost search by block and the block rule over the due blocks.

The interval of :mod:`mpmref.steppers.asynchronous` keeps three stores of the same particle fields: the
authoritative particles, their shadows and the shadows proposed at the current tick. A level update copies
rows of them into one group, runs the ordinary substep on it and copies rows back; these functions do the
copies in one compiled call each (every field at once), find the ghosts of an update among the blocks near it
(:func:`zone`, :func:`bucket_by_block`, :func:`bucket_zone_members`) and relevel the blocks due at a tick
(:func:`blocks_by_level`, :func:`relevel_due`), each in time proportional to what it visits. They are
scheduling, not physics: every backend's stages run on the groups they build, so the bookkeeping is written
once for all of them.

A store is handed over as a tuple of 2D views, one per field, ``(n, width)`` (:func:`row_views`), so that one
call loops over every field whatever its shape and dtype.
"""

import numpy as np
from numba import literal_unroll, njit, prange

from ..backends.numba.twin import parallel_kernel

#: particles per task of the parallel passes over the particles at a step boundary
CHUNK = 512


@njit(cache=True)
def chunks(n):
    """The number of :data:`CHUNK`-sized tasks covering ``n`` particles."""
    return (n + CHUNK - 1) // CHUNK


def row_views(arrays):
    """Each array as an ``(n, width)`` view (a C-contiguous array's reshape is a view), in a tuple."""
    return tuple(a.reshape(a.shape[0], -1) for a in arrays)


@njit(cache=True)
def move_rows(pairs, src_idx, dst_idx):
    """``dst[dst_idx[k]] = src[src_idx[k]]`` for every ``(src, dst)`` pair of row views: a gather, a scatter or a
    copy between stores of the same rows (one function for all three, so each kind of store compiles once)."""
    for pair in literal_unroll(pairs):
        src, dst = pair
        for k in range(src_idx.shape[0]):
            i, j = src_idx[k], dst_idx[k]
            for c in range(src.shape[1]):
                dst[j, c] = src[i, c]


@njit(cache=True)
def gather_ghosts(level_pairs, shadow_pairs, level_ghosts, shadow_ghosts, start):
    """A level update's ghosts copied into the rows from ``start`` on, in one call: the rows ``level_ghosts`` through
    ``level_pairs`` (every field, from the particles), then the rows ``shadow_ghosts`` through ``shadow_pairs`` (the
    shadows' fields, the others from the particles): :func:`move_rows` twice."""
    move_rows(level_pairs, level_ghosts, span(start, level_ghosts.shape[0]))
    move_rows(shadow_pairs, shadow_ghosts, span(start + level_ghosts.shape[0], shadow_ghosts.shape[0]))


@njit(cache=True)
def span(start, n):
    """The rows ``start .. start + n - 1`` of a group, as an index array for :func:`move_rows`."""
    return np.arange(start, start + n)


@njit(cache=True)
def zone(active, base, reach, node_shape):
    """The ghost zone of a level update: every node within ``reach`` nodes, per axis, of the base node
    ``base[a]`` of some particle ``a`` of ``active`` (index arrays into the particle arrays; ``node_shape`` the
    node lattice). Returns ``(lo, shape, mark)``: the zone's bounding box (first node and extent, clipped to
    the lattice) and a C-ordered 0/1 mark over it.

    The Chebyshev dilation of the active base nodes by ``reach`` is built on their bounding box (grown by
    ``reach``) by one running-window pass per axis, so the cost is that of the box and of the particles, not
    of the grid; a level update builds it once and tests every candidate ghost against it (:func:`zone_test`).
    """
    d = base.shape[1]
    lo = np.empty(d, np.int64)
    hi = np.empty(d, np.int64)
    for a in range(d):
        lo[a], hi[a] = base[active[0], a], base[active[0], a]
    for k in range(active.shape[0]):
        for a in range(d):
            lo[a] = min(lo[a], base[active[k], a])
            hi[a] = max(hi[a], base[active[k], a])
    shape = np.empty(d, np.int64)
    for a in range(d):
        lo[a] = max(lo[a] - reach, 0)
        shape[a] = min(hi[a] + reach, node_shape[a] - 1) - lo[a] + 1
    strides = np.ones(d, np.int64)
    for a in range(d - 2, -1, -1):
        strides[a] = strides[a + 1] * shape[a + 1]
    total = strides[0] * shape[0]
    mark = np.zeros(total, np.uint8)
    for k in range(active.shape[0]):
        flat = 0
        for a in range(d):
            flat += (base[active[k], a] - lo[a]) * strides[a]
        mark[flat] = 1
    grown = np.empty(total, np.uint8)
    for a in range(d):
        length, step = shape[a], strides[a]
        for outer in range(total // (length * step)):
            for inner in range(step):
                start = outer * length * step + inner  # the first node of a line along axis a
                count = 0  # marks in the window [j - reach, j + reach] of the line
                for j in range(min(reach, length - 1) + 1):
                    count += mark[start + j * step]
                for j in range(length):
                    grown[start + j * step] = 1 if count > 0 else 0
                    if j + reach + 1 < length:
                        count += mark[start + (j + reach + 1) * step]
                    if j - reach >= 0:
                        count -= mark[start + (j - reach) * step]
        mark, grown = grown, mark
    return lo, shape, mark


@njit(cache=True)
def in_zone(lo, shape, mark, node, p):
    """Whether the node ``node[p]`` lies in the zone ``(lo, shape, mark)`` of :func:`zone`."""
    flat = 0
    for a in range(lo.shape[0]):
        offset = node[p, a] - lo[a]
        if offset < 0 or offset >= shape[a]:
            return False
        flat = flat * shape[a] + offset
    return mark[flat] == 1


@njit(cache=True)
def zone_test(lo, shape, mark, candidates, candidate_base):
    """The ``candidates`` whose base node ``candidate_base[c]`` lies in the zone ``(lo, shape, mark)`` of
    :func:`zone`, in the order of ``candidates``."""
    keep = np.empty(candidates.shape[0], np.int64)
    n = 0
    for k in range(candidates.shape[0]):
        if in_zone(lo, shape, mark, candidate_base, candidates[k]):
            keep[n] = candidates[k]
            n += 1
    return keep[:n]


@njit(cache=True)
def zone_members(active, base, candidates, candidate_base, reach, node_shape):
    """The ``candidates`` whose base node ``candidate_base[c]`` lies within ``reach`` nodes, per axis, of the
    base node ``base[a]`` of some particle ``a`` of ``active``, in the order of ``candidates``: :func:`zone`
    then :func:`zone_test`."""
    lo, shape, mark = zone(active, base, reach, node_shape)
    return zone_test(lo, shape, mark, candidates, candidate_base)


@njit(cache=True)
def bucket_by_block(idx, owner):
    """The particles ``idx`` bucketed by their block ``owner[p]``: ``(members, blocks, starts)``, the particles
    ordered by block, the blocks that hold some (ascending) and where each block's particles start in
    ``members`` (``starts[-1]`` = their count). Built once per cohort, so that a ghost search visits the
    blocks near a level update instead of every waiting or mid-step particle (:func:`bucket_zone_members`)."""
    k_lo, k_hi = 0, -1
    for k in range(idx.shape[0]):
        b = owner[idx[k]]
        if k == 0 or b < k_lo:
            k_lo = b
        if k == 0 or b > k_hi:
            k_hi = b
    count = np.zeros(k_hi - k_lo + 2, np.int64)  # a counting sort over the range of blocks they own
    for k in range(idx.shape[0]):
        count[owner[idx[k]] - k_lo + 1] += 1
    n_blocks = 0
    for j in range(1, count.shape[0]):
        if count[j] > 0:
            n_blocks += 1
        count[j] += count[j - 1]
    blocks = np.empty(n_blocks, np.int64)
    starts = np.empty(n_blocks + 1, np.int64)
    j = 0
    for b in range(count.shape[0] - 1):
        if count[b + 1] > count[b]:
            blocks[j] = b + k_lo
            starts[j] = count[b]
            j += 1
    starts[n_blocks] = idx.shape[0]
    members = np.empty(idx.shape[0], np.int64)
    for k in range(idx.shape[0]):  # in the order of idx within a block
        b = owner[idx[k]] - k_lo
        members[count[b]] = idx[k]
        count[b] += 1
    return members, blocks, starts


@njit(cache=True)
def bucket_zone_members(lo, shape, mark, drift, block, blocks_per_axis, members, blocks, starts, candidate_base):
    """The particles of a cohort (:func:`bucket_by_block`: ``members`` by block) whose base node
    ``candidate_base[p]`` lies in the zone ``(lo, shape, mark)`` of :func:`zone`, and how many were examined.

    Only the blocks whose nodes, grown by ``drift`` nodes per axis, meet the zone's box are visited: a
    particle's ``candidate_base`` (a shadow's base node) lies at most ``drift`` nodes from the base node that
    gave it its block. The result is in bucket order (the caller sorts)."""
    d = lo.shape[0]
    keep = np.empty(members.shape[0], np.int64)
    n = 0
    examined = 0
    cell = np.empty(d, np.int64)
    for j in range(blocks.shape[0]):
        flat = blocks[j]
        for a in range(d - 1, -1, -1):
            cell[a] = flat % blocks_per_axis[a]
            flat //= blocks_per_axis[a]
        meets = True
        for a in range(d):
            if (cell[a] + 1) * block - 1 + drift < lo[a] or cell[a] * block - drift > lo[a] + shape[a] - 1:
                meets = False
                break
        if not meets:
            continue
        for k in range(starts[j], starts[j + 1]):
            examined += 1
            if in_zone(lo, shape, mark, candidate_base, members[k]):
                keep[n] = members[k]
                n += 1
    return keep[:n], examined


@njit(cache=True)
def base_node(x, origin, dx, shift, node_shape, base, a):
    """Stencil base node of position ``x`` along axis ``a``: ``floor((x - origin) / dx - shift)`` clipped to
    the node lattice (``shift`` the kernel's ``base_shift``: 1/2 quadratic, 1 cubic, 0 linear)."""
    b = np.int64(np.floor((x - origin[a]) / dx - shift))
    return min(max(b, 0), node_shape[a] - 1)


@njit(parallel=True, cache=True)  # not a twin kernel: boundary_steps, compiled, calls it
def boundary_nodes(x, idx, origin, dx, shift, node_shape, block, blocks_per_axis, base, owner):
    """At a step boundary of the particles ``idx``: their base nodes ``base`` and owner blocks ``owner`` (C order
    of the block lattice ``blocks_per_axis``), in parallel. ``block`` (cells per block edge) is a power of two, so
    a node's block coordinate is a shift of its index."""
    d, n = x.shape[1], idx.shape[0]
    bits = level_of(block)
    for c in prange(chunks(n)):
        for k in range(c * CHUNK, min(n, (c + 1) * CHUNK)):
            p = idx[k]
            flat = 0
            for a in range(d):
                b = base_node(x[p, a], origin, dx, shift, node_shape, base, a)
                base[p, a] = b
                flat = flat * blocks_per_axis[a] + (b >> bits)
            owner[p] = flat


@njit(cache=True)
def shadow_nodes(x, idx, origin, dx, shift, node_shape, end, shadow_base, shadow_t, base):
    """Base node and tick ``end`` of the shadows ``idx`` (positions ``x`` of the shadow store); returns how far,
    in nodes per axis, the farthest of them lies from its particle's base node ``base`` (that of its step's
    start, which gave the particle its block)."""
    drift = 0
    for k in range(idx.shape[0]):
        p = idx[k]
        for a in range(x.shape[1]):
            shadow_base[p, a] = base_node(x[p, a], origin, dx, shift, node_shape, shadow_base, a)
            drift = max(drift, abs(shadow_base[p, a] - base[p, a]))
        shadow_t[p] = end
    return drift


@njit(parallel=True, cache=True)  # not a twin kernel: boundary_steps, compiled, calls it
def particle_steps(idx, block_dt, owner, alignment, limit, dt_p):
    """Each particle's step at its boundary: its block's step, capped by the tick's ``alignment`` and by the
    largest power of two within its own ``limit`` (ticks, >= 1), in parallel; returns the set of steps taken, as
    the bits of an integer (steps are powers of two)."""
    n = idx.shape[0]
    taken = np.zeros(chunks(n), np.int64)
    for c in prange(chunks(n)):
        steps = np.int64(0)
        for k in range(c * CHUNK, min(n, (c + 1) * CHUNK)):
            p = idx[k]
            own = np.int64(1)
            while 2 * own <= limit[k]:
                own *= 2
            dt = min(block_dt[owner[p]], alignment, own)
            dt_p[p] = dt
            steps |= dt
        taken[c] = steps
    steps = np.int64(0)
    for c in range(taken.shape[0]):
        steps |= taken[c]
    return steps


@njit(cache=True)
def relevel_one(dt, limit, t):
    """The block step rule at a block boundary (Fang et al. 2018 §4), for one block: halve ``dt`` while above
    ``limit`` (it stays aligned, as ``t`` is a multiple of the old step), then double it while the double fits and is
    aligned (``t mod 2 dt = 0``); ``dt``, ``limit`` and ``t`` in ticks. Called for the blocks due at a tick by
    :func:`relevel_due`."""
    while dt > limit:
        dt //= 2
    while 2 * dt <= limit and t & (2 * dt - 1) == 0:  # t mod 2 dt = 0 (steps are powers of two)
        dt *= 2
    return dt


@njit(cache=True)
def level_of(dt):
    """log2 of a power of two."""
    k = 0
    while (np.int64(1) << k) < dt:
        k += 1
    return k


@njit(cache=True)
def blocks_by_level(block_dt, n_levels):
    """The blocks ordered by their step: ``(order, level_start)``, where the blocks of step ``2^k`` are
    ``order[level_start[k]:level_start[k + 1]]`` (``n_levels + 2`` entries; steps ``1 .. 2^n_levels``)."""
    level_start = np.zeros(n_levels + 2, np.int64)
    for b in range(block_dt.shape[0]):
        level_start[level_of(block_dt[b]) + 1] += 1
    for k in range(n_levels + 1):
        level_start[k + 1] += level_start[k]
    fill = level_start[:-1].copy()
    order = np.empty(block_dt.shape[0], np.int64)
    for b in range(block_dt.shape[0]):
        k = level_of(block_dt[b])
        order[fill[k]] = b
        fill[k] += 1
    return order, level_start


@njit(cache=True)
def relevel_due(block_dt, order, level_start, owner, idx, limit, t, alignment, max_units, block_limit):
    """The block step rule at tick ``t`` (Fang et al. 2018 §4), in place, visiting only the blocks due at ``t``
    and those that own some of the particles ``idx`` (at their boundary, with step limits ``limit``).

    A due block (``t mod dt = 0``, i.e. ``dt <= alignment``: the first ``level_start[log2 alignment + 1]``
    blocks of ``order``, :func:`blocks_by_level`) that owns some of ``idx`` relevels (:func:`relevel_one`) to the
    smallest of their limits; a due block that owns none follows the coarsest of the blocks that own some
    (``max_units`` if none does). Relevelling keeps a due block's step at most ``alignment`` and leaves the other
    blocks alone, so the due blocks stay the same prefix of ``order``, which is sorted again by step.
    ``block_limit`` is scratch over the blocks, every entry infinite on entry and on return. Returns the count of
    due blocks.

    Taking instead every particle whose stencil touches the block's nodes was tried: it cost 15 % of the
    stork's savings and did not reduce the error of colliding balls (docs/async.md), so the reference rule
    stays."""
    owning = np.empty(min(idx.shape[0], block_dt.shape[0]), np.int64)  # the blocks owning some, once each
    n_owning = 0
    for k in range(idx.shape[0]):
        b = owner[idx[k]]
        if block_limit[b] == np.inf:
            owning[n_owning] = b
            n_owning += 1
        block_limit[b] = min(block_limit[b], limit[k])
    coarsest = 0
    for j in range(n_owning):
        b = owning[j]
        if t & (block_dt[b] - 1) == 0:  # due: t mod dt = 0
            block_dt[b] = relevel_one(block_dt[b], np.int64(min(block_limit[b], max_units)), t)
        coarsest = max(coarsest, block_dt[b])
        block_limit[b] = -np.inf  # owns some: not an empty block below
    if coarsest == 0:
        coarsest = max_units
    due = level_start[level_of(alignment) + 1]
    for j in range(due):
        b = order[j]
        if block_limit[b] == -np.inf:
            continue
        block_dt[b] = relevel_one(block_dt[b], coarsest, t)
    for j in range(n_owning):
        block_limit[owning[j]] = np.inf
    # the due blocks, sorted by their new steps (all still at most ``alignment``)
    top = level_of(alignment)
    count = np.zeros(top + 2, np.int64)
    for j in range(due):
        count[level_of(block_dt[order[j]]) + 1] += 1
    for k in range(top + 1):
        count[k + 1] += count[k]
    for k in range(top + 1):
        level_start[k] = count[k]
    prefix = order[:due].copy()
    for j in range(due):
        k = level_of(block_dt[prefix[j]])
        order[count[k]] = prefix[j]
        count[k] += 1
    return due


@parallel_kernel(cache=True)
def step_limits(v, idx, wave_speed, dx, strength, advection, tick, max_step_s, max_units):
    r"""Step limit in ticks of the particles ``idx`` (Fang et al. 2018's rule; module docstring of
    :mod:`mpmref.steppers.asynchronous`):
    :math:`\min(\lfloor \min(S_p, A_p) \rfloor, 2^{levels})` with
    :math:`S_p = s \min(\Delta x / (c_p + |v_p|), t_{max}) / \Delta t_u` and
    :math:`A_p = a\, \Delta x / (|v_p|\, \Delta t_u)` (no advection limit at rest). ``wave_speed`` holds
    :math:`c_p` of each particle of ``idx``; returns float64 (m,). In parallel, one division per limit (the
    constant factors taken out once)."""
    n = idx.shape[0]
    out = np.empty(n)
    strength_ticks, cap = strength * dx / tick, strength * max_step_s / tick
    advection_ticks = advection * dx / tick
    for c in prange(chunks(n)):
        for k in range(c * CHUNK, min(n, (c + 1) * CHUNK)):
            p = idx[k]
            speed2 = 0.0
            for a in range(v.shape[1]):
                speed2 += np.float64(v[p, a]) ** 2
            speed = np.sqrt(speed2)
            limit = min(strength_ticks / max(wave_speed[k] + speed, 1e-300), cap)
            if speed > 0:
                limit = min(limit, advection_ticks / speed)
            out[k] = min(np.floor(limit), max_units)
    return out


@njit(cache=True)
def add_impulses(dP, dL, first, n_active, shadow_ghosts, first_shadow, impulse, moment):
    """A level update's impulses and moments (``impulse``, ``moment``: one row per row of the update) added to the
    registers ``dP``, ``dL`` of its active particles (rows ``first .. first + n_active - 1``, the update's first
    rows) and of its shadow ghosts' particles ``shadow_ghosts`` (the update's rows from ``first_shadow`` on)."""
    for k in range(n_active):
        for c in range(dP.shape[1]):
            dP[first + k, c] += impulse[k, c]
        for c in range(dL.shape[1]):
            dL[first + k, c] += moment[k, c]
    for k in range(shadow_ghosts.shape[0]):
        for c in range(dP.shape[1]):
            dP[shadow_ghosts[k], c] += impulse[first_shadow + k, c]
        for c in range(dL.shape[1]):
            dL[shadow_ghosts[k], c] += moment[first_shadow + k, c]


@njit(cache=True)
def apply_registers_at(idx, x, v, C, mass, dP, dL, inertia):
    r"""Apply and clear the impulse registers of the particles ``idx`` at their step end: the formula of
    :func:`mpmref.physics.interface.apply_registers`, one particle at a time,

    .. math:: v_p \mathrel{+}= \delta P_p / m_p, \qquad
              C_p \mathrel{+}= W\big((\delta L_p - x_p \times \delta P_p) / (m_p D_p)\big)

    (``C`` empty for PIC and FLIP; ``dL`` (n, 1) in 2D, (n, 3) in 3D; ``inertia`` :math:`D_p`). Empty registers
    are skipped.

    Docs: docs/async.md#conservative-interfaces
    """
    d = x.shape[1]
    for k in range(idx.shape[0]):
        p = idx[k]
        empty = True  # most particles never meet an interface: nothing to apply or clear
        for a in range(dP.shape[1]):
            empty = empty and dP[p, a] == 0.0
        for a in range(dL.shape[1]):
            empty = empty and dL[p, a] == 0.0
        if empty:
            continue
        m = np.float64(mass[p])
        for a in range(d):
            v[p, a] += dP[p, a] / m
        if C.shape[0] > 0:
            if d == 2:
                spin = (dL[p, 0] - (x[p, 0] * dP[p, 1] - x[p, 1] * dP[p, 0])) / (m * inertia)
                C[p, 1, 0] += 0.5 * spin
                C[p, 0, 1] -= 0.5 * spin
            else:
                s0 = (dL[p, 0] - (x[p, 1] * dP[p, 2] - x[p, 2] * dP[p, 1])) / (m * inertia)
                s1 = (dL[p, 1] - (x[p, 2] * dP[p, 0] - x[p, 0] * dP[p, 2])) / (m * inertia)
                s2 = (dL[p, 2] - (x[p, 0] * dP[p, 1] - x[p, 1] * dP[p, 0])) / (m * inertia)
                C[p, 2, 1] += 0.5 * s0
                C[p, 1, 2] -= 0.5 * s0
                C[p, 0, 2] += 0.5 * s1
                C[p, 2, 0] -= 0.5 * s1
                C[p, 1, 0] += 0.5 * s2
                C[p, 0, 1] -= 0.5 * s2
        for a in range(dP.shape[1]):
            dP[p, a] = 0.0
        for a in range(dL.shape[1]):
            dL[p, a] = 0.0


@njit(cache=True)
def misplaced_rows(level, n_due, top):
    """The rows ``0 .. n_due - 1``, whose particles have steps ``2^level`` (``level`` up to ``top``), ordered by step
    with the fewest moves: ``(src, dst, level_start)``, where the particles of step ``2^k`` are to occupy rows
    ``level_start[k] .. level_start[k + 1] - 1`` and the particle in row ``src[i]`` moves to row ``dst[i]``.

    Only the particles outside their step's run move: the ``i``-th of them with step ``2^k`` (in row order) takes
    the ``i``-th row of the run of ``2^k`` held by a particle of another step (the moves are a permutation of
    those rows, :func:`permute_rows`). A prefix already ordered by step gives no moves."""
    level_start = np.zeros(top + 2, np.int64)
    for r in range(n_due):
        level_start[level[r] + 1] += 1
    for k in range(top + 1):
        level_start[k + 1] += level_start[k]
    # rows of run k held by others ("holes") and particles of step k outside run k ("movers"): as many of each
    holes = np.zeros(top + 2, np.int64)
    run = 0
    for r in range(n_due):
        while r >= level_start[run + 1]:
            run += 1
        if level[r] != run:
            holes[run + 1] += 1
    for k in range(top + 1):
        holes[k + 1] += holes[k]
    m = holes[top + 1]
    src = np.empty(m, np.int64)
    dst = np.empty(m, np.int64)
    next_hole = holes[:-1].copy()
    next_mover = holes[:-1].copy()
    run = 0
    for r in range(n_due):
        while r >= level_start[run + 1]:
            run += 1
        k = level[r]
        if k != run:
            dst[next_hole[run]] = r  # a hole of run ``run``, in row order
            next_hole[run] += 1
            src[next_mover[k]] = r  # a mover into run ``k``, in row order: paired with run k's holes
            next_mover[k] += 1
    return src, dst, level_start


@njit(cache=True)
def permute_rows(views, src, dst):
    """``a[dst[i]] = a[src[i]]`` at once for every row view ``a`` of ``views`` (``src`` and ``dst`` the same set of
    rows, :func:`misplaced_rows`), through a copy of the rows that move."""
    for a in literal_unroll(views):
        moving = np.empty((src.shape[0], a.shape[1]), a.dtype)
        for i in range(src.shape[0]):
            for c in range(a.shape[1]):
                moving[i, c] = a[src[i], c]
        for i in range(src.shape[0]):
            for c in range(a.shape[1]):
                a[dst[i], c] = moving[i, c]


@njit(cache=True)
def same_ids(before, after):
    """Whether ``after`` holds exactly the ids of ``before``, each once (ids are non-negative integers): one pass
    over each and a mark per id, what the census of every synchronised time costs when the rows were reordered."""
    if before.shape[0] != after.shape[0]:
        return False
    top = 0
    for k in range(before.shape[0]):
        top = max(top, before[k])
    seen = np.zeros(top + 1, np.int8)
    for k in range(before.shape[0]):
        seen[before[k]] = 1
    for k in range(after.shape[0]):
        i = after[k]
        if i < 0 or i > top or seen[i] != 1:
            return False
        seen[i] = 2
    return True


@njit(cache=True)
def boundary_steps(x, idx, origin, dx, shift, node_shape, block, blocks_per_axis, limit, t, alignment, room,
                   max_units, block_dt, order, level_start, block_limit, base, owner, dt_p):
    """Everything the particles ``idx`` at their step boundary (tick ``t``, step limits ``limit``) decide, in one
    call: their base nodes and blocks (:func:`boundary_nodes`), the blocks due at ``t`` relevelled
    (:func:`relevel_due`, with ``alignment`` and ``max_units``), and each particle's step, capped at ``room``
    (:func:`particle_steps`). Returns ``(steps taken as bits, due blocks)``."""
    boundary_nodes(x, idx, origin, dx, shift, node_shape, block, blocks_per_axis, base, owner)
    due = relevel_due(block_dt, order, level_start, owner, idx, limit, t, alignment, max_units, block_limit)
    return particle_steps(idx, block_dt, owner, room, limit, dt_p), due


@njit(cache=True)
def levels_of(dt_p, n, level):
    """``level[r] = log2 dt_p[r]`` for the rows ``0 .. n - 1`` (the particles' levels, from their steps)."""
    for r in range(n):
        level[r] = level_of(dt_p[r])

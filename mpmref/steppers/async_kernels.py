"""Compiled bookkeeping of asynchronous stepping: row copies between particle stores and the ghost zone.

The interval of :mod:`mpmref.steppers.asynchronous` keeps three stores of the same particle fields: the
authoritative particles, their shadows and the shadows proposed at the current tick. A level update copies
rows of them into one group, runs the ordinary substep on it and copies rows back; these functions do the
copies in one compiled call each (every field at once) and find the ghosts of an update. They are
scheduling, not physics: every backend's stages run on the groups they build, so the bookkeeping is written
once for all of them.

A store is handed over as a tuple of 2D views, one per field, ``(n, width)`` (:func:`row_views`), so that one
call loops over every field whatever its shape and dtype.
"""

import numpy as np
from numba import literal_unroll, njit


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


def span(start, n):
    """The rows ``start .. start + n - 1`` of a group, as an index array for :func:`move_rows`."""
    return np.arange(start, start + n, dtype=np.int64)


@njit(cache=True)
def clock_scan(t_p, t):
    """The particles at tick ``t`` (their clock ``t_p`` is ``t``) and those past it, as two index arrays."""
    n_at = 0
    n_past = 0
    for i in range(t_p.shape[0]):
        if t_p[i] == t:
            n_at += 1
        elif t_p[i] > t:
            n_past += 1
    at = np.empty(n_at, np.int64)
    past = np.empty(n_past, np.int64)
    n_at = 0
    n_past = 0
    for i in range(t_p.shape[0]):
        if t_p[i] == t:
            at[n_at] = i
            n_at += 1
        elif t_p[i] > t:
            past[n_past] = i
            n_past += 1
    return at, past


@njit(cache=True)
def zone_members(active, base, candidates, candidate_base, reach, node_shape):
    """The ``candidates`` whose base node ``candidate_base[c]`` lies within ``reach`` nodes, per axis, of the
    base node ``base[a]`` of some particle ``a`` of ``active`` (index arrays into the particle arrays;
    ``node_shape`` the node lattice), in the order of ``candidates``.

    The Chebyshev dilation of the active base nodes by ``reach`` is built on their bounding box (grown by
    ``reach`` and clipped to the lattice) by one running-window pass per axis, so the cost is that of the
    box and of the particles, not of the grid.
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
        for start in range(total):
            if (start // step) % length != 0:
                continue  # not the first node of a line along axis a
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
    keep = np.empty(candidates.shape[0], np.int64)
    n = 0
    for k in range(candidates.shape[0]):
        c = candidates[k]
        flat, inside = 0, True
        for a in range(d):
            offset = candidate_base[c, a] - lo[a]
            if offset < 0 or offset >= shape[a]:
                inside = False
                break
            flat += offset * strides[a]
        if inside and mark[flat] == 1:
            keep[n] = c
            n += 1
    return keep[:n]


@njit(cache=True)
def base_node(x, origin, dx, shift, node_shape, base, a):
    """Stencil base node of position ``x`` along axis ``a``: ``floor((x - origin) / dx - shift)`` clipped to
    the node lattice (``shift`` the kernel's ``base_shift``: 1/2 quadratic, 1 cubic, 0 linear)."""
    b = np.int64(np.floor((x - origin[a]) / dx - shift))
    return min(max(b, 0), node_shape[a] - 1)


@njit(cache=True)
def boundary_nodes(x, idx, origin, dx, shift, node_shape, block, blocks_per_axis, t, base, owner, shadow_base,
                   shadow_t):
    """At a step boundary (tick ``t``) of the particles ``idx``: their base nodes ``base``, owner blocks
    ``owner`` (C order of the block lattice ``blocks_per_axis``), and their shadows' base node and tick."""
    d = x.shape[1]
    for k in range(idx.shape[0]):
        p = idx[k]
        flat = 0
        for a in range(d):
            b = base_node(x[p, a], origin, dx, shift, node_shape, base, a)
            base[p, a] = b
            shadow_base[p, a] = b
            flat = flat * blocks_per_axis[a] + b // block
        owner[p] = flat
        shadow_t[p] = t


@njit(cache=True)
def shadow_nodes(x, idx, origin, dx, shift, node_shape, end, shadow_base, shadow_t):
    """Base node and tick ``end`` of the shadows ``idx`` (positions ``x`` of the shadow store)."""
    for k in range(idx.shape[0]):
        p = idx[k]
        for a in range(x.shape[1]):
            shadow_base[p, a] = base_node(x[p, a], origin, dx, shift, node_shape, shadow_base, a)
        shadow_t[p] = end


@njit(cache=True)
def particle_steps(idx, block_dt, owner, alignment, limit, dt_p):
    """Each particle's step at its boundary: its block's step, capped by the tick's ``alignment`` and by the
    largest power of two within its own ``limit`` (ticks, >= 1); returns the set of steps taken, as the bits
    of an integer (steps are powers of two)."""
    steps = 0
    for k in range(idx.shape[0]):
        p = idx[k]
        own = np.int64(1)
        while 2 * own <= limit[k]:
            own *= 2
        dt = min(block_dt[owner[p]], alignment, own)
        dt_p[p] = dt
        steps |= dt
    return steps


@njit(cache=True)
def relevel_one(dt, limit, t):
    """:func:`mpmref.steppers.asynchronous.relevel` for one block: halve while above ``limit``, then double
    while the double fits and is aligned (``t mod 2 dt = 0``)."""
    while dt > limit:
        dt //= 2
    while 2 * dt <= limit and t % (2 * dt) == 0:
        dt *= 2
    return dt


@njit(cache=True)
def relevel_blocks(block_dt, owner, idx, limit, t, max_units):
    """New block steps at tick ``t`` (Fang et al. 2018 §4): a block due at ``t`` that owns some of the
    particles ``idx`` (at their boundary, with step limits ``limit``) relevels (:func:`relevel_one`) to the
    smallest of their limits; a due block that owns none follows the coarsest of the blocks that own some.

    Taking instead every particle whose stencil touches the block's nodes was tried: it cost 15 % of the
    stork's savings and did not reduce the error of colliding balls (docs/async.md), so the reference rule
    stays."""
    n_blocks = block_dt.shape[0]
    block_limit = np.full(n_blocks, np.inf)
    for k in range(idx.shape[0]):
        b = owner[idx[k]]
        block_limit[b] = min(block_limit[b], limit[k])
    new = block_dt.copy()
    coarsest = 0
    for b in range(n_blocks):
        if np.isfinite(block_limit[b]):
            if t % block_dt[b] == 0:
                new[b] = relevel_one(block_dt[b], np.int64(min(block_limit[b], max_units)), t)
            coarsest = max(coarsest, new[b])
    if coarsest == 0:
        coarsest = max_units
    for b in range(n_blocks):
        if not np.isfinite(block_limit[b]) and t % block_dt[b] == 0:
            new[b] = relevel_one(block_dt[b], coarsest, t)
    return new


@njit(cache=True)
def step_limits(v, idx, wave_speed, dx, strength, advection, tick, max_step_s, max_units):
    r"""Step limit in ticks of the particles ``idx`` (Fang et al. 2018's rule; module docstring of
    :mod:`mpmref.steppers.asynchronous`):
    :math:`\min(\lfloor \min(S_p, A_p) \rfloor, 2^{levels})` with
    :math:`S_p = s \min(\Delta x / (c_p + |v_p|), t_{max}) / \Delta t_u` and
    :math:`A_p = a\, \Delta x / (|v_p|\, \Delta t_u)` (no advection limit at rest). ``wave_speed`` holds
    :math:`c_p` of each particle of ``idx``; returns float64 (m,)."""
    out = np.empty(idx.shape[0])
    for k in range(idx.shape[0]):
        p = idx[k]
        speed2 = 0.0
        for a in range(v.shape[1]):
            speed2 += np.float64(v[p, a]) ** 2
        speed = np.sqrt(speed2)
        limit = strength * min(dx / max(wave_speed[k] + speed, 1e-300), max_step_s) / tick
        if speed > 0:
            limit = min(limit, advection * dx / (max(speed, 1e-300) * tick))
        out[k] = min(np.floor(limit), max_units)
    return out


@njit(cache=True)
def add_rows(dst, idx, src, start):
    """``dst[idx[k]] += src[start + k]`` (rows of 2D arrays): a particle's register takes an update's impulse."""
    for k in range(idx.shape[0]):
        for c in range(dst.shape[1]):
            dst[idx[k], c] += src[start + k, c]


@njit(cache=True)
def apply_registers(idx, x, v, C, mass, dP, dL, inertia):
    r"""Apply and clear the impulse registers of the particles ``idx`` at their step end: the formula of
    :func:`mpmref.physics.interface.apply_registers`, one particle at a time,

    .. math:: v_p \mathrel{+}= \delta P_p / m_p, \qquad
              C_p \mathrel{+}= W\big((\delta L_p - x_p \times \delta P_p) / (m_p D_p)\big)

    (``C`` empty for PIC and FLIP; ``dL`` (n, 1) in 2D, (n, 3) in 3D; ``inertia`` :math:`D_p`).

    Docs: docs/async.md#conservative-interfaces
    """
    d = x.shape[1]
    for k in range(idx.shape[0]):
        p = idx[k]
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

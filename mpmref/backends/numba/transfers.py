r"""P2G, grid update and G2P of the Numba backend: the equations of
:mod:`mpmref.backends.numpy.transfers`, one particle at a time with the stencil inside.

Each kernel is built for one transfer configuration (of a :class:`~mpmref.physics.scheme.TransferSpec`):
dimension, kernel, block size, scheme features (affine matrix, PolyPIC modes, FLIP in G2P) and force
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
owner block and of that block's upper neighbours (:func:`block_rows_2d`, :func:`block_rows_3d`:
:math:`2^{d-1}` look-ups in the block-pointer table), and per axis which of them each stencil node falls in
and its offset inside; per node only a sum and a choice between two registers remain, as cheap as the
strides of a dense grid.
"""

import hashlib
from functools import lru_cache
from pathlib import Path

import numpy as np
from numba import njit, prange

from .materials import fluid_stress_into
from .stencil import KERNEL_CODES, kernel_axis, polypic_axis_basis


def _source_digest():
    """Hash of this backend's source files.

    Numba's on-disk cache of a function is invalidated only when *its own* file changes, not when a jitted
    function it calls from another file does. Each transfer kernel carries this digest as a closure
    constant, which Numba's cache key includes, so editing any file of the backend recompiles them.
    """
    h = hashlib.sha256()
    for path in sorted(Path(__file__).parent.rglob("*.py")):
        h.update(path.read_bytes())
    return h.hexdigest()


SOURCE_DIGEST = _source_digest()


def make_p2g(transfer, block, fluids_only, fused=False):
    """P2G kernel for a :class:`~mpmref.physics.scheme.TransferSpec` on a grid of ``block``-cell blocks, for a scene
    of ``fluids_only`` or one with solids (FLIP, the tracked deformation and which solids are invisible to
    P2G, so those variants share one compiled kernel), ``fused`` or not (the internal force folded into the
    momentum); see :func:`p2g_kernel`."""
    return p2g_kernel(transfer.dim, KERNEL_CODES[transfer.kernel], transfer.support, transfer.affine, transfer.polypic,
                      transfer.mls_force, block, fluids_only, fused)


def make_g2p(transfer, block):
    """G2P kernel for a :class:`~mpmref.physics.scheme.TransferSpec` on a grid of ``block``-cell blocks (the tracked
    deformation, F or J, is a run-time choice, so those variants share one compiled kernel); see
    :func:`g2p_kernel`."""
    return g2p_kernel(transfer.dim, KERNEL_CODES[transfer.kernel], transfer.support, transfer.affine, transfer.polypic,
                      transfer.flip, transfer.mls_gradient, block)


def make_kick_gather(transfer, block):
    """The kick gather of conservative level interfaces for a configuration; see :func:`kick_gather_kernel`."""
    return kick_gather_kernel(transfer.dim, KERNEL_CODES[transfer.kernel], transfer.support, block)


@lru_cache(maxsize=None)
def p2g_kernel(DIM, KERNEL, S, AFFINE, POLY, MLS_FORCE, BLOCK, FLUIDS_ONLY, FUSED=False):
    r"""P2G kernel: node mass, momentum and internal force (Hu et al. 2018 Eq. 18; see
    :func:`mpmref.backends.numpy.transfers.p2g` for the equations).

    The returned function ``p2g(x, v, C, modes, mass, vol0, stress, J, material, fluid_params, layout,
    mode_index, particle_groups, class_rows, dt, grid)`` adds into the zeroed ``grid`` (rows, 1 + 2d), one row per
    node of the active blocks of a :class:`~.sparse.BlockLayout` (``layout`` a
    :class:`~.kernel_args.SparseLayout`: ``origin``, ``dx``, ``inertia``, ``slot_of`` the block-pointer table,
    ``table_strides`` the table's strides; rows located by :func:`block_rows_2d` and :func:`block_rows_3d`):
    mass, momentum, internal force, group by group (``particle_groups`` a :class:`~.kernel_args.Groups`: slabs
    or blocks, ``order[group_start[g]:group_start[g + 1]]`` the particles of group ``g``) in
    the colours of :mod:`.blocks` (run it with a parallel chunk size of 1: groups hold unequal numbers of
    particles, so they are handed to the threads one at a time). Per particle it first computes what every
    node of its stencil shares, once: the Kirchhoff stress :math:`\tau_p` (read from ``stress``, the stress
    stage's (n, d, d) output; with ``FLUIDS_ONLY``, every material of the scene is a weakly compressible
    fluid, ``stress`` is empty, and the stress, a function of :math:`J_p` alone, is computed here with the
    stress stage's own :func:`~mpmref.backends.numba.materials.fluid_stress_into` and the parameters
    ``fluid_params[material[p]]``, cheaper than storing it and reading it back; the solids' laws stay out of
    this kernel, which is why one compiled P2G serves every scene with solids), the force matrix
    :math:`Q_p = -V_p^0 \tau_p D_p^{-1}` (MLS-MPM) or :math:`-V_p^0\tau_p` (classic), the affine momentum
    :math:`m_p C_p` and the momentum :math:`m_p v_p`, and per axis the weights, node offsets :math:`x_i - x_p` and (classic)
    weight derivatives. Per node it then forms only products: :math:`f_i \mathrel{+}= Q_p\, w_{ip}(x_i - x_p)`
    for MLS-MPM and :math:`Q_p \nabla w_{ip}` for classic MPM (:func:`p2g_node`). Products are contracted to
    fused multiply-adds where the CPU has them (``fastmath={"contract"}``, no other fast-math licence: still
    IEEE operations, one rounding fewer). With particle classes (a level update of asynchronous stepping with
    conservative interfaces, :mod:`mpmref.physics.interface`), ``class_rows[p]`` is the first row of particle
    ``p``'s class in a ``grid`` that holds one block of rows per class, so the classes are summed apart in
    this one pass; ``class_rows`` is empty otherwise.

    ``FUSED`` (:func:`mpmref.backends.numpy.transfers.p2g_fused`): ``grid`` has rows (1 + d), mass and the momentum
    after the force :math:`(mv)_i + \Delta t f_i`; with the MLS force the stress joins the affine matrix once per
    particle, :math:`A_p = m_p C_p + \Delta t Q_p` (formed in a small per-group array: Numba's parallel array
    analysis refuses a tuple assigned from several producers), and each node takes
    :math:`w_{ip}(m_p v_p + A_p(x_i - x_p))`; with the classic force it takes :math:`\Delta t Q_p \nabla w_{ip}`
    beside the momentum (``dt`` is unused otherwise; no particle classes).

    Docs: docs/performance.md#the-fused-p2g
    """
    SOURCES = SOURCE_DIGEST
    N = BLOCK**DIM  # nodes (rows) per block

    @njit(parallel=True, cache=True, fastmath={"contract"})
    def p2g(x, v, C, modes, mass, vol0, stress, J, material, fluid_params, layout, mode_index, particle_groups,
            class_rows, dt, grid):
        SOURCES  # noqa: B018 - a closure constant: part of the cache key (see _source_digest)
        origin, dx, inertia, slot_of, table_strides = layout
        order, group_start, groups, colour_start = particle_groups
        inv_dx = 1.0 / dx
        real = grid.dtype.type
        for colour in range(colour_start.shape[0] - 1):
            first = colour_start[colour]
            for si in prange(colour_start[colour + 1] - first):
                group = groups[first + si]
                fluid_tau = np.empty((DIM, DIM), grid.dtype)  # one allocation per group
                folded = np.empty((DIM, DIM), grid.dtype)
                q = np.empty((DIM if POLY else 0, S, S))
                qnorm = np.empty((DIM if POLY else 0, S))
                w_arr = np.empty((DIM if POLY else 0, S))
                fx_arr = np.empty(DIM if POLY else 0)
                for k in range(group_start[group], group_start[group + 1]):
                    p = order[k]
                    shift = class_rows[p] if class_rows.shape[0] > 0 else 0  # the particle's class's rows
                    if FLUIDS_ONLY:  # a closure constant: the other branch is not compiled
                        prm = fluid_params[material[p]]
                        fluid_stress_into(J[p], prm[0], prm[1], fluid_tau)
                        tau = fluid_tau
                    else:
                        tau = stress[p]
                    m = mass[p]
                    # the force matrix; a fused P2G scales the classic force's by dt (the MLS one joins mC below)
                    scale = -vol0[p] / inertia if MLS_FORCE else -vol0[p] * (dt if FUSED else 1.0)
                    Q = matrix(tau, real(scale), DIM)
                    mv = scaled_row(v, p, m, DIM)
                    if FUSED and MLS_FORCE:  # the stress joins the affine matrix once: A_p = m_p C_p + dt Q_p
                        for a in range(DIM):
                            for b in range(DIM):
                                folded[a, b] = (m * C[p, a, b] if AFFINE else 0.0) + real(dt) * Q[a][b]
                        mC = matrix(folded, real(1.0), DIM)
                    elif AFFINE:
                        mC = matrix(C[p], m, DIM)
                    else:
                        mC = Q  # unused
                    b0, f0, w0, d0, g0, wt0 = axis_stencil(KERNEL, x[p, 0], origin[0], dx, inv_dx, real, S)
                    b1, f1, w1, d1, g1, wt1 = axis_stencil(KERNEL, x[p, 1], origin[1], dx, inv_dx, real, S)
                    if DIM == 2:
                        k0, k1 = block_rows_2d(b0, b1, slot_of, table_strides, BLOCK)
                        l0, l1 = b0 % BLOCK, b1 % BLOCK
                        c0, r0 = hops(l0, BLOCK, S), local_rows(l0, BLOCK, BLOCK, 0, S)
                        r1 = local_rows(l1, BLOCK, 1, N, S)
                        if POLY:
                            for j in range(S):
                                w_arr[0, j], w_arr[1, j] = w0[j], w1[j]
                            fx_arr[0], fx_arr[1] = f0, f1
                            polypic_axis_basis(w_arr, fx_arr, dx, q, qnorm)
                        for i in range(S):
                            row_i = (k1 if c0[i] else k0) + r0[i] + shift
                            for j in range(S):
                                w = wt0[i] * wt1[j]
                                d = (d0[i], d1[j])
                                fw = (w * d[0], w * d[1]) if MLS_FORCE else (g0[i] * wt1[j], g1[j] * wt0[i])
                                p2g_node(grid, row_i + r1[j], w, d, fw, (i, j), m, mv, mC, Q, p, modes, q, mode_index,
                                         AFFINE or (FUSED and MLS_FORCE), POLY, FUSED, MLS_FORCE)
                    else:
                        b2, f2, w2, d2, g2, wt2 = axis_stencil(KERNEL, x[p, 2], origin[2], dx, inv_dx, real, S)
                        k00, k01, k10, k11 = block_rows_3d(b0, b1, b2, slot_of, table_strides, BLOCK)
                        l0, l1, l2 = b0 % BLOCK, b1 % BLOCK, b2 % BLOCK
                        c0, c1 = hops(l0, BLOCK, S), hops(l1, BLOCK, S)
                        r0, r1 = local_rows(l0, BLOCK, BLOCK * BLOCK, 0, S), local_rows(l1, BLOCK, BLOCK, 0, S)
                        r2 = local_rows(l2, BLOCK, 1, N, S)
                        if POLY:
                            for j in range(S):
                                w_arr[0, j], w_arr[1, j], w_arr[2, j] = w0[j], w1[j], w2[j]
                            fx_arr[0], fx_arr[1], fx_arr[2] = f0, f1, f2
                            polypic_axis_basis(w_arr, fx_arr, dx, q, qnorm)
                        for i in range(S):
                            ka, kb = (k10, k11) if c0[i] else (k00, k01)
                            for j in range(S):
                                w01 = wt0[i] * wt1[j]
                                row_ij = (kb if c1[j] else ka) + r0[i] + r1[j] + shift
                                for l in range(S):
                                    w = w01 * wt2[l]
                                    d = (d0[i], d1[j], d2[l])
                                    if MLS_FORCE:
                                        fw = (w * d[0], w * d[1], w * d[2])
                                    else:
                                        fw = (g0[i] * wt1[j] * wt2[l], g1[j] * wt0[i] * wt2[l], g2[l] * w01)
                                    p2g_node(grid, row_ij + r2[l], w, d, fw, (i, j, l), m, mv, mC, Q, p, modes, q,
                                             mode_index, AFFINE or (FUSED and MLS_FORCE), POLY, FUSED, MLS_FORCE)

    return p2g


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
    along axis 0 (look-ups in the block-pointer table ``slot_of``; see :mod:`.sparse`).

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


@njit(cache=True, inline="always")
def offsets(f, dx, S):
    """Node offsets :math:`(k - f)\\Delta x`, ``k = 0 .. S-1``, of one axis as a tuple."""
    if S == 2:
        return ((0.0 - f) * dx, (1.0 - f) * dx)
    if S == 3:
        return ((0.0 - f) * dx, (1.0 - f) * dx, (2.0 - f) * dx)
    return ((0.0 - f) * dx, (1.0 - f) * dx, (2.0 - f) * dx, (3.0 - f) * dx)


@njit(cache=True, inline="always")
def scaled(t, s, S):
    """``s * t`` for a tuple ``t`` of ``S`` = 2 to 4 values."""
    if S == 2:
        return (s * t[0], s * t[1])
    if S == 3:
        return (s * t[0], s * t[1], s * t[2])
    return (s * t[0], s * t[1], s * t[2], s * t[3])


@njit(cache=True, inline="always")
def cast(t, real, S):
    """A tuple ``t`` of ``S`` = 2 to 4 values converted to the scalar type ``real`` (so a float32 run's
    per-node arithmetic stays in float32)."""
    if S == 2:
        return (real(t[0]), real(t[1]))
    if S == 3:
        return (real(t[0]), real(t[1]), real(t[2]))
    return (real(t[0]), real(t[1]), real(t[2]), real(t[3]))


@njit(cache=True, inline="always")
def axis_stencil(KERNEL, x_a, origin_a, dx, inv_dx, real, S):
    r"""One axis ``a`` of a particle's transfer stencil, the set-up that P2G and G2P share: the base node
    :math:`b`, the fraction :math:`f = (x_a - o_a)/\Delta x - b`, the weights :math:`N_k` (as the kernel gives
    them), and cast to the run's scalar type ``real`` the node offsets :math:`(k - f)\Delta x`, the weight
    derivatives :math:`N'_k/\Delta x` and the weights (:func:`mpmref.backends.numba.stencil.kernel_axis`)."""
    b, f, w, dw = kernel_axis(KERNEL, (x_a - origin_a) / dx)
    return b, f, w, cast(offsets(f, dx, S), real, S), cast(scaled(dw, inv_dx, S), real, S), cast(w, real, S)


@njit(cache=True, inline="always")
def row(a, p, dim):
    """``a[p]`` of an (n, d) array as a d-tuple (held in registers by the compiled loop)."""
    if dim == 2:
        return (a[p, 0], a[p, 1])
    return (a[p, 0], a[p, 1], a[p, 2])


@njit(cache=True, inline="always")
def scaled_row(a, p, scale, dim):
    """``scale * a[p]`` of an (n, d) array as a d-tuple."""
    if dim == 2:
        return (scale * a[p, 0], scale * a[p, 1])
    return (scale * a[p, 0], scale * a[p, 1], scale * a[p, 2])


@njit(cache=True, inline="always")
def matrix(a, scale, dim):
    """``scale * a`` of a (d, d) array as a d-tuple of d-tuples."""
    if dim == 2:
        return ((scale * a[0, 0], scale * a[0, 1]), (scale * a[1, 0], scale * a[1, 1]))
    return ((scale * a[0, 0], scale * a[0, 1], scale * a[0, 2]),
            (scale * a[1, 0], scale * a[1, 1], scale * a[1, 2]),
            (scale * a[2, 0], scale * a[2, 1], scale * a[2, 2]))


@njit(cache=True, inline="always")
def p2g_node(grid, idx, w, d, fw, ks, m, mv, mC, Q, p, modes, q, mode_index, affine, poly, fused, mls_force):
    r"""P2G scatter of one particle to one node ``idx`` of ``grid`` (rows: mass, momentum, force):
    :math:`w_{ip} m_p`, :math:`w_{ip} (m_p v_p + m_p C_p (x_i - x_p) + m_p \sum_r c_{pr} s_r(x_i))` and
    :math:`Q_p\, \mathrm{fw}` (``d`` = :math:`x_i - x_p`; ``fw`` = :math:`w_{ip}(x_i - x_p)` with the MLS
    force matrix :math:`Q_p = -V_p^0\tau_p D_p^{-1}`, or :math:`\nabla w_{ip}` with the classic
    :math:`Q_p = -V_p^0\tau_p`; ``ks`` the node's per-axis stencil index; ``mv``, ``mC``, ``Q`` are the
    particle's values as tuples). ``fused`` (rows: mass, momentum after the force): ``mC`` holds
    :math:`A_p = m_p C_p + \Delta t Q_p` with the MLS force, and with the classic force ``Q`` holds
    :math:`\Delta t Q_p`, added to the momentum instead of a force column."""
    dim = len(d)
    grid[idx, 0] += w * m
    for a in range(dim):
        mom = mv[a]
        if affine:
            for b in range(dim):
                mom += mC[a][b] * d[b]
        if poly:
            for r in range(mode_index.shape[0]):
                s = m
                for c in range(dim):
                    s *= q[c, mode_index[r, c], ks[c]]
                mom += s * modes[p, r, a]
        if fused and not mls_force:
            f = Q[a][0] * fw[0]
            for b in range(1, dim):
                f += Q[a][b] * fw[b]
            grid[idx, 1 + a] += w * mom + f
        elif fused:
            grid[idx, 1 + a] += w * mom
        else:
            grid[idx, 1 + a] += w * mom
            f = Q[a][0] * fw[0]
            for b in range(1, dim):
                f += Q[a][b] * fw[b]
            grid[idx, 1 + dim + a] += f


@lru_cache(maxsize=None)
def g2p_kernel(DIM, KERNEL, S, AFFINE, POLY, FLIP, MLS_GRADIENT, BLOCK):
    r"""G2P kernel: PIC velocity, affine matrix, PolyPIC modes, FLIP blend, F or J and position
    (Jiang et al. 2015 §5; Hu et al. 2018 §4; see :func:`mpmref.backends.numpy.transfers.g2p`).

    The returned ``g2p(x, v, F, J, layout, dt, flip_alpha, mode_index, v_grid, v_tilde, x_new, v_new, C_new,
    F_new, J_new, modes_new)`` (``layout`` a :class:`~.kernel_args.SparseLayout`) writes the new particle arrays from the
    node velocities on the rows of a :class:`~.sparse.BlockLayout` (see :func:`p2g_kernel`). A gather writes
    only its own particle, so it runs in parallel over the particles in their storage order. The sums over the stencil
    are held as tuples, in the run's dtype: :math:`\sum_i w_{ip} v_i`,
    :math:`B_p = \sum_i w_{ip} v_i (x_i - x_p)^T`, :math:`\sum_i v_i \nabla w_{ip}^T` (classic force) and
    :math:`-\sum_i w_{ip} \tilde v_i` (FLIP); PolyPIC's mode projections go to a work array
    (:func:`gather_modes`).
    ``MLS_GRADIENT``: the velocity gradient is MLS's, :math:`\nabla v_p = C_p` (``transfer.mls_gradient``), chosen
    apart from the force. ``F_new`` or ``J_new`` is empty where the state does not track that quantity: a run-time
    test per particle, so one compiled kernel serves scenes that track F, J or both.
    """
    NEED_B = AFFINE or MLS_GRADIENT
    SOURCES = SOURCE_DIGEST
    N = BLOCK**DIM

    @njit(parallel=True, cache=True, fastmath={"contract"})
    def g2p(x, v, F, J, layout, dt, flip_alpha, mode_index, v_grid, v_tilde, x_new, v_new, C_new, F_new, J_new,
            modes_new):
        SOURCES  # noqa: B018 - a closure constant: part of the cache key (see _source_digest)
        origin, dx, inertia, slot_of, table_strides = layout
        n_modes = mode_index.shape[0]
        real = x_new.dtype.type
        inv_dx = 1.0 / dx
        n = x.shape[0]
        for chunk in prange((n + G2P_CHUNK - 1) // G2P_CHUNK):
            q = np.empty((DIM, S, S))
            qnorm = np.empty((DIM, S))
            w_arr = np.empty((DIM, S))
            fx_arr = np.empty(DIM)
            acc = np.empty((max(n_modes, 1), DIM))
            for p in range(chunk * G2P_CHUNK, min(n, (chunk + 1) * G2P_CHUNK)):
                if POLY:
                    acc[:] = 0.0
                v_pic, dv_flip = zeros(real, DIM), zeros(real, DIM)
                B, grad_v = zeros2(real, DIM), zeros2(real, DIM)
                b0, f0, w0, d0, g0, wt0 = axis_stencil(KERNEL, x[p, 0], origin[0], dx, inv_dx, real, S)
                b1, f1, w1, d1, g1, wt1 = axis_stencil(KERNEL, x[p, 1], origin[1], dx, inv_dx, real, S)
                if DIM == 2:
                    k0, k1 = block_rows_2d(b0, b1, slot_of, table_strides, BLOCK)
                    l0, l1 = b0 % BLOCK, b1 % BLOCK
                    c0, r0 = hops(l0, BLOCK, S), local_rows(l0, BLOCK, BLOCK, 0, S)
                    r1 = local_rows(l1, BLOCK, 1, N, S)
                    if POLY:
                        for j in range(S):
                            w_arr[0, j], w_arr[1, j] = w0[j], w1[j]
                        fx_arr[0], fx_arr[1] = f0, f1
                        polypic_axis_basis(w_arr, fx_arr, dx, q, qnorm)
                    for i in range(S):
                        row_i = (k1 if c0[i] else k0) + r0[i]
                        for j in range(S):
                            idx = row_i + r1[j]
                            w = wt0[i] * wt1[j]
                            vi = row(v_grid, idx, DIM)
                            v_pic = axpy(v_pic, w, vi, DIM)
                            if NEED_B:
                                B = add_outer(B, scaled(vi, w, DIM), (d0[i], d1[j]), DIM)
                            if not MLS_GRADIENT:
                                grad_v = add_outer(grad_v, vi, (g0[i] * wt1[j], g1[j] * wt0[i]), DIM)
                            if FLIP:
                                dv_flip = axpy(dv_flip, -w, row(v_tilde, idx, DIM), DIM)
                            if POLY:
                                gather_modes(acc, idx, w, (i, j), v_grid, q, mode_index)
                else:
                    b2, f2, w2, d2, g2, wt2 = axis_stencil(KERNEL, x[p, 2], origin[2], dx, inv_dx, real, S)
                    k00, k01, k10, k11 = block_rows_3d(b0, b1, b2, slot_of, table_strides, BLOCK)
                    l0, l1, l2 = b0 % BLOCK, b1 % BLOCK, b2 % BLOCK
                    c0, c1 = hops(l0, BLOCK, S), hops(l1, BLOCK, S)
                    r0, r1 = local_rows(l0, BLOCK, BLOCK * BLOCK, 0, S), local_rows(l1, BLOCK, BLOCK, 0, S)
                    r2 = local_rows(l2, BLOCK, 1, N, S)
                    if POLY:
                        for j in range(S):
                            w_arr[0, j], w_arr[1, j], w_arr[2, j] = w0[j], w1[j], w2[j]
                        fx_arr[0], fx_arr[1], fx_arr[2] = f0, f1, f2
                        polypic_axis_basis(w_arr, fx_arr, dx, q, qnorm)
                    for i in range(S):
                        ka, kb = (k10, k11) if c0[i] else (k00, k01)
                        for j in range(S):
                            w01 = wt0[i] * wt1[j]
                            row_ij = (kb if c1[j] else ka) + r0[i] + r1[j]
                            for l in range(S):
                                idx = row_ij + r2[l]
                                w = w01 * wt2[l]
                                vi = row(v_grid, idx, DIM)
                                v_pic = axpy(v_pic, w, vi, DIM)
                                if NEED_B:
                                    B = add_outer(B, scaled(vi, w, DIM), (d0[i], d1[j], d2[l]), DIM)
                                if not MLS_GRADIENT:
                                    g = (g0[i] * wt1[j] * wt2[l], g1[j] * wt0[i] * wt2[l], g2[l] * w01)
                                    grad_v = add_outer(grad_v, vi, g, DIM)
                                if FLIP:
                                    dv_flip = axpy(dv_flip, -w, row(v_tilde, idx, DIM), DIM)
                                if POLY:
                                    gather_modes(acc, idx, w, (i, j, l), v_grid, q, mode_index)
                finish_particle(p, x, v, F, J, dt, inertia, flip_alpha, v_pic, dv_flip, B, grad_v, acc, qnorm,
                                mode_index, x_new, v_new, C_new, F_new, J_new, modes_new,
                                AFFINE, POLY, FLIP, MLS_GRADIENT, F_new.shape[0] > 0, J_new.shape[0] > 0)

    return g2p


#: particles per task of G2P's parallel loop
G2P_CHUNK = 256


@njit(cache=True, inline="always")
def zeros(real, dim):
    """A d-tuple of zeros of scalar type ``real``."""
    if dim == 2:
        return (real(0.0), real(0.0))
    return (real(0.0), real(0.0), real(0.0))


@njit(cache=True, inline="always")
def zeros2(real, dim):
    """A d x d matrix of zeros of scalar type ``real`` as a flat tuple (row-major)."""
    if dim == 2:
        return (real(0.0), real(0.0), real(0.0), real(0.0))
    return (real(0.0), real(0.0), real(0.0), real(0.0), real(0.0), real(0.0), real(0.0), real(0.0), real(0.0))


@njit(cache=True, inline="always")
def axpy(y, a, x, dim):
    """``y + a x`` of d-tuples."""
    if dim == 2:
        return (y[0] + a * x[0], y[1] + a * x[1])
    return (y[0] + a * x[0], y[1] + a * x[1], y[2] + a * x[2])


@njit(cache=True, inline="always")
def cross(a, b):
    """The cross product of 3-tuples."""
    return (a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0])


@njit(cache=True, inline="always")
def add_outer(M, u, d, dim):
    """``M + u d^T`` of a d x d matrix ``M`` held as a flat row-major tuple and d-tuples ``u``, ``d``."""
    if dim == 2:
        return (M[0] + u[0] * d[0], M[1] + u[0] * d[1], M[2] + u[1] * d[0], M[3] + u[1] * d[1])
    return (M[0] + u[0] * d[0], M[1] + u[0] * d[1], M[2] + u[0] * d[2],
            M[3] + u[1] * d[0], M[4] + u[1] * d[1], M[5] + u[1] * d[2],
            M[6] + u[2] * d[0], M[7] + u[2] * d[1], M[8] + u[2] * d[2])


@njit(cache=True, inline="always")
def gather_modes(acc, idx, w, ks, v_grid, q, mode_index):
    r"""PolyPIC's mode projections of one node: ``acc[r] += w s_r(x_i) v_i`` (``ks`` the node's per-axis stencil
    index; :math:`s_r = \prod_a q_{a, r_a}`)."""
    d = v_grid.shape[1]
    for r in range(mode_index.shape[0]):
        s = 1.0
        for c in range(d):
            s *= q[c, mode_index[r, c], ks[c]]
        for a in range(d):
            acc[r, a] += (w * s) * v_grid[idx, a]


@njit(cache=True, inline="always")
def finish_particle(p, x, v, F, J, dt, inertia, flip_alpha, v_pic, dv_flip, B, grad_v, acc, qnorm, mode_index,
                    x_new, v_new, C_new, F_new, J_new, modes_new, affine, poly, flip, mls_gradient, tracks_F,
                    tracks_J):
    r"""G2P's per-particle update from the gathered sums (see :func:`mpmref.backends.numpy.transfers.g2p`).

    :math:`C_p = B_p D_p^{-1}`; :math:`\nabla v_p = C_p` (MLS, ``mls_gradient``) or the gathered
    :math:`\sum_i v_i \nabla w_{ip}^T`;
    :math:`x_p \leftarrow x_p + \Delta t\, v^{PIC}_p`; the FLIP blend (``dv_flip`` holds
    :math:`\sum_i w_{ip}(v_i - \tilde v_i)` less :math:`v^{PIC}_p`, added back here); :math:`F_p \leftarrow
    F_p + \Delta t\, \nabla v_p F_p`; :math:`J_p \leftarrow J_p (1 + \Delta t \operatorname{tr} \nabla v_p)`;
    PolyPIC modes :math:`c_{pr} = \sum_i w_{ip} s_r v_i / \prod_a \langle q_{r_a}, q_{r_a}\rangle_a`.
    """
    d = x.shape[1]
    for a in range(d):
        x_new[p, a] = x[p, a] + dt * v_pic[a]
        if flip:
            v_new[p, a] = flip_alpha * (v[p, a] + (v_pic[a] + dv_flip[a])) + (1.0 - flip_alpha) * v_pic[a]
        else:
            v_new[p, a] = v_pic[a]
        if affine:
            for b in range(d):
                C_new[p, a, b] = B[a * d + b] / inertia
    if poly:
        for r in range(mode_index.shape[0]):
            norm = 1.0
            for a in range(d):
                norm *= qnorm[a, mode_index[r, a]]
            for a in range(d):
                modes_new[p, r, a] = acc[r, a] / norm if norm > 0 else 0.0
    if tracks_F:
        for a in range(d):
            for b in range(d):
                s = 0.0
                for c in range(d):
                    s += dt * (B[a * d + c] / inertia if mls_gradient else grad_v[a * d + c]) * F[p, c, b]
                F_new[p, a, b] = F[p, a, b] + s
    if tracks_J:
        trace = 0.0
        for a in range(d):
            trace += B[a * d + a] / inertia if mls_gradient else grad_v[a * d + a]
        J_new[p] = J[p] * (1.0 + dt * trace)


@njit(parallel=True, cache=True)
def grid_velocity(mass, momentum, force, dt, gravity, node_shape, strides, wall_width, wall_type, wall_friction,
                  v, v_tilde):
    r"""Grid update with Eq. 25 walls on the dense grid (node ``i`` at C-order index ``i``); see
    :func:`node_velocity` for the equations."""
    for i in prange(mass.shape[0]):
        if node_velocity(i, mass, momentum, force, dt, gravity, v, v_tilde):
            for a in range(momentum.shape[1]):
                project_in_bands(v, i, a, (i // strides[a]) % node_shape[a], node_shape[a], wall_width, wall_type,
                                 wall_friction)


@njit(parallel=True, cache=True)
def block_grid_velocity(mass, momentum, force, dt, gravity, node_shape, block, blocks, wall_width, wall_type,
                        wall_friction, v, v_tilde):
    r"""Grid update with Eq. 25 walls on the sparse grid (row ``r`` of the active blocks ``blocks`` of a
    :class:`~.sparse.BlockLayout`); the same per-node arithmetic as :func:`grid_velocity`."""
    d = momentum.shape[1]
    block_nodes = block**d
    for r in prange(mass.shape[0]):
        if node_velocity(r, mass, momentum, force, dt, gravity, v, v_tilde):
            slot, local = r // block_nodes, r % block_nodes
            for a in range(d):
                index = blocks[slot, a] * block + (local // block ** (d - 1 - a)) % block
                project_in_bands(v, r, a, index, node_shape[a], wall_width, wall_type, wall_friction)


@njit(cache=True, inline="always")
def node_velocity(i, mass, momentum, force, dt, gravity, v, v_tilde):
    r"""Velocity of node ``i`` before the walls (see :func:`mpmref.backends.numpy.transfers.grid_update`):

    .. math:: \tilde v_i = (mv)_i / m_i, \qquad v_i = \tilde v_i + \Delta t\,(f_i / m_i + g)

    or, with ``force`` empty (a fused P2G's momentum :math:`(mv)_i + \Delta t f_i`), :math:`v_i = ((mv)_i +
    \Delta t f_i)/m_i + \Delta t g` and no :math:`\tilde v_i`. Nodes without mass get zero velocity; returns
    whether the node has mass.
    """
    d = momentum.shape[1]
    folded = force.shape[0] == 0  # a fused P2G's momentum already holds dt f: no v_tilde
    if mass[i] <= 0:
        for a in range(d):
            v[i, a] = 0.0
            if not folded:
                v_tilde[i, a] = 0.0
        return False
    inv_m = 1.0 / mass[i]
    for a in range(d):
        if folded:
            v[i, a] = momentum[i, a] * inv_m + dt * gravity[a]
        else:
            v_tilde[i, a] = momentum[i, a] * inv_m
            v[i, a] = (momentum[i, a] + dt * force[i, a]) * inv_m + dt * gravity[a]
    return True


@njit(cache=True, inline="always")
def project_in_bands(v, i, axis, index, n_axis, wall_width, wall_type, wall_friction):
    """The walls of ``axis`` at node ``i``, whose node index along it is ``index`` (of ``n_axis``): the talk's
    Eq. 25 projection with the wall's inward normal where the node lies within ``wall_width`` cells of it, the
    lower wall first (the reference's order; a corner node is projected by each of its walls in turn).
    ``wall_type[2a + side]``: 0 open, 1 sticky, 2 slip, 3 separate; ``wall_friction`` the Coulomb μ."""
    if index < wall_width:
        project_at_wall(v, i, axis, 1.0, wall_type[2 * axis], wall_friction[2 * axis])
    if index > n_axis - 1 - wall_width:
        project_at_wall(v, i, axis, -1.0, wall_type[2 * axis + 1], wall_friction[2 * axis + 1])


@njit(cache=True)
def project_at_wall(v, i, axis, sign, kind, friction):
    r"""Talk Eq. 25 at an axis-aligned wall with inward normal ``sign * e_axis`` (see
    :func:`mpmref.physics.boundary.project_velocity`)."""
    d = v.shape[1]
    if kind == 0:
        return
    if kind == 1:
        for a in range(d):
            v[i, a] = 0.0
        return
    vn = v[i, axis] * sign
    if kind == 2:
        v[i, axis] -= vn * sign
        return
    if vn >= 0.0:
        return
    vt_norm2 = 0.0
    for a in range(d):
        if a != axis:
            vt_norm2 += v[i, a] ** 2
    vt_norm = np.sqrt(vt_norm2)
    if vt_norm <= -friction * vn:
        for a in range(d):
            v[i, a] = 0.0
        return
    scale = 1.0 + friction * vn / vt_norm
    v[i, axis] = 0.0
    for a in range(d):
        if a != axis:
            v[i, a] *= scale


@njit(cache=True)
def class_totals(class_sums, total):
    """``total[r] = class_sums[0, r] + class_sums[1, r] + class_sums[2, r]``: the node sums of a P2G by
    particle classes (:mod:`mpmref.physics.interface`), row by row (serial: a pass over memory, which a second
    thread hardly speeds up, and a parallel loop takes seconds longer to compile)."""
    for r in range(total.shape[0]):
        for c in range(total.shape[1]):
            total[r, c] = class_sums[0, r, c] + class_sums[1, r, c] + class_sums[2, r, c]


@njit(cache=True)
def node_kicks(class_sums, dt, kappa, kicks):
    r"""The node kicks of impulse refluxing, row by row (the equations of
    :func:`mpmref.physics.interface.interface_kicks`): ``kicks[0]`` :math:`= -I_i(A \leftarrow F)/m^A_i` for
    the active particles, ``kicks[1]`` :math:`= -I_i(A \leftarrow S)/m^S_i` for the coarser shadows, with
    :math:`I_i(A \leftarrow Y) = (\kappa (m^A (mv)^Y - m^Y (mv)^A) + \Delta t (m^A f^Y - m^Y f^A)) / m_i`;
    zero where the receiving class (or the node) has no mass.

    Docs: docs/async.md#what-is-conserved-at-level-interfaces
    """
    d = kicks.shape[2]
    for r in range(kicks.shape[1]):
        mA, mF, mS = class_sums[0, r, 0], class_sums[1, r, 0], class_sums[2, r, 0]
        m = mA + mF + mS
        for k in range(2):
            y, receiver = (1, mA) if k == 0 else (2, mS)
            mY = class_sums[y, r, 0]
            for a in range(d):
                if m > 0 and receiver > 0:
                    exchange = (kappa * (mA * class_sums[y, r, 1 + a] - mY * class_sums[0, r, 1 + a])
                                + dt * (mA * class_sums[y, r, 1 + d + a] - mY * class_sums[0, r, 1 + d + a])) / m
                    kicks[k, r, a] = -exchange / receiver
                else:
                    kicks[k, r, a] = 0.0


@lru_cache(maxsize=None)
def kick_gather_kernel(DIM, KERNEL, S, BLOCK):
    r"""The kick gather of conservative level interfaces (:mod:`mpmref.physics.interface`), a pass of its own
    after G2P, so that the G2P kernels of every other run compile without it.

    The returned ``gather(x, mass, layout, kick_rows, kicks, impulse, moment)`` (``layout`` a
    :class:`~.kernel_args.SparseLayout`) writes, for each particle ``p`` with ``kick_rows[p] >= 0`` (the first row of its class's kicks in
    ``kicks``), its impulse :math:`\delta P_p = m_p \sum_i w_{ip} k_i` into ``impulse[p]`` and its moment about
    the origin :math:`\delta L_p = m_p (x_p \times \sum_i w_{ip} k_i + \sum_i w_{ip} (x_i - x_p) \times k_i)`
    into ``moment[p]`` (one column in 2D, three in 3D), in float64; the nodes are the rows of a
    :class:`~.sparse.BlockLayout`, addressed as in :func:`g2p_kernel`.

    Docs: docs/async.md#conservative-interfaces
    """
    SOURCES = SOURCE_DIGEST
    N = BLOCK**DIM

    @njit(parallel=True, cache=True, fastmath={"contract"})
    def gather(x, mass, layout, kick_rows, kicks, impulse, moment):
        SOURCES  # noqa: B018 - a closure constant: part of the cache key (see _source_digest)
        origin, dx, inertia, slot_of, table_strides = layout
        for p in prange(x.shape[0]):
            first = kick_rows[p]
            if first < 0:
                continue
            kp, kl = zeros(np.float64, DIM), zeros(np.float64, 3)
            b0, f0, w0, _ = kernel_axis(KERNEL, (x[p, 0] - origin[0]) / dx)
            b1, f1, w1, _ = kernel_axis(KERNEL, (x[p, 1] - origin[1]) / dx)
            d0, d1 = offsets(f0, dx, S), offsets(f1, dx, S)
            if DIM == 2:
                k0, k1 = block_rows_2d(b0, b1, slot_of, table_strides, BLOCK)
                l0, l1 = b0 % BLOCK, b1 % BLOCK
                c0, r0 = hops(l0, BLOCK, S), local_rows(l0, BLOCK, BLOCK, 0, S)
                r1 = local_rows(l1, BLOCK, 1, N, S)
                for i in range(S):
                    row_i = (k1 if c0[i] else k0) + r0[i] + first
                    for j in range(S):
                        kick = scaled(row(kicks, row_i + r1[j], DIM), w0[i] * w1[j], DIM)
                        kp = axpy(kp, 1.0, kick, DIM)
                        kl = (kl[0], kl[1], kl[2] + d0[i] * kick[1] - d1[j] * kick[0])
            else:
                b2, f2, w2, _ = kernel_axis(KERNEL, (x[p, 2] - origin[2]) / dx)
                d2 = offsets(f2, dx, S)
                k00, k01, k10, k11 = block_rows_3d(b0, b1, b2, slot_of, table_strides, BLOCK)
                l0, l1, l2 = b0 % BLOCK, b1 % BLOCK, b2 % BLOCK
                c0, c1 = hops(l0, BLOCK, S), hops(l1, BLOCK, S)
                r0, r1 = local_rows(l0, BLOCK, BLOCK * BLOCK, 0, S), local_rows(l1, BLOCK, BLOCK, 0, S)
                r2 = local_rows(l2, BLOCK, 1, N, S)
                for i in range(S):
                    ka, kb = (k10, k11) if c0[i] else (k00, k01)
                    for j in range(S):
                        row_ij = (kb if c1[j] else ka) + r0[i] + r1[j] + first
                        for l in range(S):
                            kick = scaled(row(kicks, row_ij + r2[l], DIM), w0[i] * w1[j] * w2[l], DIM)
                            kp = axpy(kp, 1.0, kick, DIM)
                            kl = axpy(kl, 1.0, cross((d0[i], d1[j], d2[l]), kick), 3)
            m = np.float64(mass[p])
            xp = (np.float64(x[p, 0]), np.float64(x[p, 1]), np.float64(x[p, 2]) if DIM == 3 else 0.0)
            about_origin = axpy(kl, 1.0, cross(xp, (kp[0], kp[1], kp[2] if DIM == 3 else 0.0)), 3)
            for a in range(DIM):
                impulse[p, a] = m * kp[a]
            for a in range(moment.shape[1]):
                moment[p, a] = m * about_origin[3 - moment.shape[1] + a]

    return gather

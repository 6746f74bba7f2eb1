r"""The transfer kernels of the Numba backend in 2D: P2G, G2P and the kick gather of conservative level
interfaces, one particle at a time with its :math:`S^2` stencil inside (the equations of
:mod:`mpmref.backends.numpy.transfers`). :mod:`.transfers3d` has the same kernels, with the same arguments, in
3D; :data:`.transfers.TRANSFER_KERNELS` holds both.

The nodes are rows of the sparse grid (:mod:`.sparse`): per particle, the first rows of its owner block and of
the block above it along axis 0 (:func:`~.sparse.block_rows_2d`), and per axis which of them each stencil node
falls in (:func:`~.sparse.hops`) and its row offset inside (:func:`~.sparse.local_rows`).
"""

from functools import lru_cache

import numpy as np
from numba import prange

from ..pointwise.laws import WORK, functions, law_digest
from ..pointwise.stencil import axis_basis, kernel_axis
from .g2p import G2P_CHUNK, deform_particle, gather_modes, move_particle
from .materials import bound
from .p2g import p2g_node
from .source_digest import SOURCE_DIGEST
from .sparse import block_rows_2d, hops, local_rows
from .stencil import axis_stencil, offsets, scaled
from .tuple_math import add_outer, axpy, cross, matrix, row, scaled_row, zeros, zeros2
from .twin import parallel_kernel

#: the law by which P2G computes the stress where it does: each kernel reads its own (:func:`.materials.bound`)
law_stress = None


@lru_cache(maxsize=None)
def p2g_kernel(KERNEL, S, AFFINE, POLY, MLS_FORCE, BLOCK, STRESS_LAW, FUSED=False):
    r"""P2G kernel: node mass, momentum and internal force (Hu et al. 2018 Eq. 18; see
    :func:`mpmref.backends.numpy.transfers.p2g` for the equations).

    The returned function ``p2g(x, v, C, modes, mass, vol0, stress, J, material, params, layout, mode_index,
    particle_groups, class_rows, dt, grid)`` adds into the zeroed ``grid`` (rows, 1 + 2d), one row per
    node of the active blocks of a :class:`~.sparse.BlockLayout` (``layout`` a
    :class:`~.kernel_args.SparseLayout`: ``origin``, ``dx``, ``inertia``, ``slot_of`` the block-pointer table,
    ``table_strides`` the table's strides; rows located by :func:`~.sparse.block_rows_2d`):
    mass, momentum, internal force, group by group (``particle_groups`` a :class:`~.kernel_args.Groups`: slabs
    or blocks, ``order[group_start[g]:group_start[g + 1]]`` the particles of group ``g``) in
    the colours of :mod:`.blocks` (run it with a parallel chunk size of 1: groups hold unequal numbers of
    particles, so they are handed to the threads one at a time). Per particle it first computes what every
    node of its stencil shares, once: the Kirchhoff stress :math:`\tau_p` (read from ``stress``, the stress
    stage's (n, d, d) output; with ``STRESS_LAW``, the one law of every material of the scene, a law of :math:`J`
    alone (a :class:`~mpmref.physics.materials.CompiledLaw`, the fluid's in the examples), ``stress`` is empty and
    the stress is computed here by that law's pointwise function with the parameter rows ``params[material[p]]``,
    cheaper than storing it and reading it back; the solids' laws stay out of this kernel, which is why one
    compiled P2G serves every scene with solids), the force matrix
    :math:`Q_p = -V_p^0 \tau_p D_p^{-1}` (MLS-MPM) or :math:`-V_p^0\tau_p` (classic), the affine momentum
    :math:`m_p C_p` and the momentum :math:`m_p v_p`, and per axis the weights, node offsets :math:`x_i - x_p` and
    (classic) weight derivatives. Per node it then forms only products: :math:`f_i \mathrel{+}= Q_p\, w_{ip}(x_i - x_p)`
    for MLS-MPM and :math:`Q_p \nabla w_{ip}` for classic MPM (:func:`~.p2g.p2g_node`). The sums of products
    over the stencil are fused multiply-adds written out (:func:`~.tuple_math.fma`: one rounding fewer, and the
    same in every build of the kernel). With particle classes (a level update of asynchronous stepping with
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
    N = BLOCK**2  # nodes (rows) per block

    FLUIDS_ONLY = bool(STRESS_LAW)  # a law, or none
    LAW = law_digest(STRESS_LAW) if FLUIDS_ONLY else ""

    def p2g(x, v, C, modes, mass, vol0, stress, J, material, params, layout, mode_index, particle_groups,
            class_rows, dt, grid):
        SOURCES, LAW  # noqa: B018 - closure constants: part of the cache key (see source_digest)
        origin, dx, inertia, slot_of, table_strides = layout
        order, group_start, groups, colour_start = particle_groups
        inv_dx = 1.0 / dx
        real = grid.dtype.type
        for colour in range(colour_start.shape[0] - 1):
            first = colour_start[colour]
            for si in prange(colour_start[colour + 1] - first):
                group = groups[first + si]
                fluid_tau = np.empty((2, 2), grid.dtype)  # one allocation per group
                work = np.empty((WORK if FLUIDS_ONLY else 0, 2, 2), grid.dtype)
                folded = np.empty((2, 2), grid.dtype)
                q = np.empty((2 if POLY else 0, S, S))
                qnorm = np.empty((2 if POLY else 0, S))
                w_arr = np.empty((2 if POLY else 0, S))
                fx_arr = np.empty(2 if POLY else 0)
                for k in range(group_start[group], group_start[group + 1]):
                    p = order[k]
                    shift = class_rows[p] if class_rows.shape[0] > 0 else 0  # the particle's class's rows
                    if FLUIDS_ONLY:  # a closure constant: the other branch is not compiled
                        law_stress(params[material[p]], fluid_tau, J[p], real(1.0), fluid_tau, work)
                        tau = fluid_tau
                    else:
                        tau = stress[p]
                    m = mass[p]
                    # the force matrix; a fused P2G scales the classic force's by dt (the MLS one joins mC below)
                    scale = -vol0[p] / inertia if MLS_FORCE else -vol0[p] * (dt if FUSED else 1.0)
                    Q = matrix(tau, real(scale), 2)
                    mv = scaled_row(v, p, m, 2)
                    if FUSED and MLS_FORCE:  # the stress joins the affine matrix once: A_p = m_p C_p + dt Q_p
                        for a in range(2):
                            for b in range(2):
                                folded[a, b] = (m * C[p, a, b] if AFFINE else 0.0) + real(dt) * Q[a][b]
                        mC = matrix(folded, real(1.0), 2)
                    elif AFFINE:
                        mC = matrix(C[p], m, 2)
                    else:
                        mC = Q  # unused
                    b0, f0, w0, d0, g0, wt0 = axis_stencil(KERNEL, x[p, 0], origin[0], dx, inv_dx, real, S)
                    b1, f1, w1, d1, g1, wt1 = axis_stencil(KERNEL, x[p, 1], origin[1], dx, inv_dx, real, S)
                    k0, k1 = block_rows_2d(b0, b1, slot_of, table_strides, BLOCK)
                    l0, l1 = b0 % BLOCK, b1 % BLOCK
                    c0, r0 = hops(l0, BLOCK, S), local_rows(l0, BLOCK, BLOCK, 0, S)
                    r1 = local_rows(l1, BLOCK, 1, N, S)
                    if POLY:
                        for j in range(S):
                            w_arr[0, j], w_arr[1, j] = w0[j], w1[j]
                        fx_arr[0], fx_arr[1] = f0, f1
                        for a in range(2):
                            axis_basis(w_arr[a], fx_arr[a], dx, q[a], qnorm[a])
                    for i in range(S):
                        row_i = (k1 if c0[i] else k0) + r0[i] + shift
                        for j in range(S):
                            w = wt0[i] * wt1[j]
                            d = (d0[i], d1[j])
                            fw = (w * d[0], w * d[1]) if MLS_FORCE else (g0[i] * wt1[j], g1[j] * wt0[i])
                            p2g_node(grid, row_i + r1[j], w, d, fw, (i, j), m, mv, mC, Q, p, modes, q, mode_index,
                                     AFFINE or (FUSED and MLS_FORCE), POLY, FUSED, MLS_FORCE)

    return parallel_kernel(
        bound(p2g, law_stress=functions(STRESS_LAW).stress if FLUIDS_ONLY else None), cache=True)


@lru_cache(maxsize=None)
def g2p_kernel(KERNEL, S, AFFINE, POLY, FLIP, MLS_GRADIENT, BLOCK):
    r"""G2P kernel: PIC velocity, affine matrix, PolyPIC modes, FLIP blend, F or J and position
    (Jiang et al. 2015 §5; Hu et al. 2018 §4; see :func:`mpmref.backends.numpy.transfers.g2p`).

    The returned ``g2p(x, v, F, J, rows, layout, dt, flip_alpha, mode_index, v_grid, v_tilde, x_new, v_new, C_new,
    F_new, J_new, modes_new)`` (``layout`` a :class:`~.kernel_args.SparseLayout`) writes the new particle arrays
    from the node velocities on the rows of a
    :class:`~.sparse.BlockLayout` (see :func:`p2g_kernel`): of every particle when ``rows`` is empty, else of the
    particles ``rows`` only, each into its own row of the new arrays (which may be the particle arrays themselves:
    a particle reads its own state before writing it, so G2P runs in place, as asynchronous stepping's level
    updates do, :meth:`mpmref.backends.base.RowBackend.g2p_rows`). A gather writes
    only its own particle, so it runs in parallel over the particles in their storage order. The sums over the stencil
    are held as tuples, in the run's dtype: :math:`\sum_i w_{ip} v_i`,
    :math:`B_p = \sum_i w_{ip} v_i (x_i - x_p)^T`, :math:`\sum_i v_i \nabla w_{ip}^T` (classic force) and
    :math:`-\sum_i w_{ip} \tilde v_i` (FLIP); PolyPIC's mode projections go to a work array
    (:func:`~.g2p.gather_modes`); :func:`~.g2p.move_particle` and :func:`~.g2p.deform_particle` update the particle
    from them.
    ``MLS_GRADIENT``: the velocity gradient is MLS's, :math:`\nabla v_p = C_p` (``transfer.mls_gradient``), chosen
    apart from the force. ``F_new`` or ``J_new`` is empty where the state does not track that quantity: a run-time
    test per particle, so one compiled kernel serves scenes that track F, J or both.
    """
    NEED_B = AFFINE or MLS_GRADIENT
    SOURCES = SOURCE_DIGEST
    N = BLOCK**2

    @parallel_kernel(cache=True)
    def g2p(x, v, F, J, rows, layout, dt, flip_alpha, mode_index, v_grid, v_tilde, x_new, v_new, C_new, F_new, J_new,
            modes_new):
        SOURCES  # noqa: B018 - a closure constant: part of the cache key (see source_digest)
        origin, dx, inertia, slot_of, table_strides = layout
        n_modes = mode_index.shape[0]
        real = x_new.dtype.type
        inv_dx = 1.0 / dx
        some = rows.shape[0] > 0
        n = rows.shape[0] if some else x.shape[0]
        for chunk in prange((n + G2P_CHUNK - 1) // G2P_CHUNK):
            q = np.empty((2, S, S))
            qnorm = np.empty((2, S))
            w_arr = np.empty((2, S))
            fx_arr = np.empty(2)
            acc = np.empty((max(n_modes, 1), 2))
            for k in range(chunk * G2P_CHUNK, min(n, (chunk + 1) * G2P_CHUNK)):
                p = rows[k] if some else np.int64(k)
                if POLY:
                    acc[:] = 0.0
                v_pic, dv_flip = zeros(real, 2), zeros(real, 2)
                B, grad_v = zeros2(real, 2), zeros2(real, 2)
                b0, f0, w0, d0, g0, wt0 = axis_stencil(KERNEL, x[p, 0], origin[0], dx, inv_dx, real, S)
                b1, f1, w1, d1, g1, wt1 = axis_stencil(KERNEL, x[p, 1], origin[1], dx, inv_dx, real, S)
                k0, k1 = block_rows_2d(b0, b1, slot_of, table_strides, BLOCK)
                l0, l1 = b0 % BLOCK, b1 % BLOCK
                c0, r0 = hops(l0, BLOCK, S), local_rows(l0, BLOCK, BLOCK, 0, S)
                r1 = local_rows(l1, BLOCK, 1, N, S)
                if POLY:
                    for j in range(S):
                        w_arr[0, j], w_arr[1, j] = w0[j], w1[j]
                    fx_arr[0], fx_arr[1] = f0, f1
                    for a in range(2):
                        axis_basis(w_arr[a], fx_arr[a], dx, q[a], qnorm[a])
                for i in range(S):
                    row_i = (k1 if c0[i] else k0) + r0[i]
                    for j in range(S):
                        idx = row_i + r1[j]
                        w = wt0[i] * wt1[j]
                        vi = row(v_grid, idx, 2)
                        v_pic = axpy(v_pic, w, vi, 2)
                        if NEED_B:
                            B = add_outer(B, scaled(vi, w, 2), (d0[i], d1[j]), 2)
                        if not MLS_GRADIENT:
                            grad_v = add_outer(grad_v, vi, (g0[i] * wt1[j], g1[j] * wt0[i]), 2)
                        if FLIP:
                            dv_flip = axpy(dv_flip, -w, row(v_tilde, idx, 2), 2)
                        if POLY:
                            gather_modes(acc, idx, w, (i, j), v_grid, q, mode_index)
                move_particle(p, x, v, dt, inertia, flip_alpha, v_pic, dv_flip, B, acc, qnorm, mode_index, x_new,
                              v_new, C_new, modes_new, AFFINE, POLY, FLIP)
                deform_particle(p, 2, F, J, dt, inertia, B, grad_v, F_new, J_new, MLS_GRADIENT, F_new.shape[0] > 0,
                                J_new.shape[0] > 0)

    return g2p


@lru_cache(maxsize=None)
def kick_gather_kernel(KERNEL, S, BLOCK):
    r"""The kick gather of conservative level interfaces (:mod:`mpmref.physics.interface`), a pass of its own
    after G2P, so that the G2P kernels of every other run compile without it.

    The returned ``gather(x, mass, rows, layout, kick_rows, kicks, kicked, impulse, moment)`` (``layout`` a
    :class:`~.kernel_args.SparseLayout`) writes, for the ``k``-th particle ``p`` of ``rows`` (``p = k`` when ``rows`` is
    empty) with ``kick_rows[k] >= 0`` (the first row of its class's kicks in ``kicks``), its impulse
    :math:`\delta P_p = m_p \sum_i w_{ip} k_i` into ``impulse[k]`` and its moment about the origin
    :math:`\delta L_p = m_p (x_p \times \sum_i w_{ip} k_i + \sum_i w_{ip} (x_i - x_p) \times k_i)` into ``moment[k]``
    (one column: the moments of 3-vectors with zero third components have only a third), in float64; the nodes are the
    rows of a :class:`~.sparse.BlockLayout`, addressed as in :func:`g2p_kernel`. ``kicked`` flags the blocks of
    ``kicks`` (its rows in blocks of :math:`B^d`, :func:`.kicks.kicked_blocks`) that hold a non-zero kick: a particle
    whose stencil reaches none is skipped (its rows of ``impulse`` and ``moment``, zero on entry, stay zero, which
    is what the sums of zero kicks give), so the pass costs what the particles near an interface cost. It reads
    the positions of the step's P2G, so it runs before a G2P in place.

    Docs: docs/async.md#conservative-interfaces
    """
    SOURCES = SOURCE_DIGEST
    N = BLOCK**2

    @parallel_kernel(cache=True)
    def gather(x, mass, rows, layout, kick_rows, kicks, kicked, impulse, moment):
        SOURCES  # noqa: B018 - a closure constant: part of the cache key (see source_digest)
        origin, dx, inertia, slot_of, table_strides = layout
        some = rows.shape[0] > 0
        n = rows.shape[0] if some else x.shape[0]
        for k in prange(n):
            p = rows[k] if some else np.int64(k)  # one integer type (prange counts unsigned)
            first = kick_rows[k]
            if first < 0:
                continue
            b0, f0, w0, _ = kernel_axis(KERNEL, np.float64, (x[p, 0] - origin[0]) / dx)
            b1, f1, w1, _ = kernel_axis(KERNEL, np.float64, (x[p, 1] - origin[1]) / dx)
            k0, k1 = block_rows_2d(b0, b1, slot_of, table_strides, BLOCK)
            s0, s1 = (first + k0) // N, (first + k1) // N  # the blocks the stencil reaches: these and the next
            if not (kicked[s0] or kicked[s0 + 1] or kicked[s1] or kicked[s1 + 1]):
                continue  # no kick there: the impulse and moment stay zero
            kp, kl = zeros(np.float64, 2), zeros(np.float64, 3)
            d0, d1 = offsets(f0, dx, S), offsets(f1, dx, S)
            l0, l1 = b0 % BLOCK, b1 % BLOCK
            c0, r0 = hops(l0, BLOCK, S), local_rows(l0, BLOCK, BLOCK, 0, S)
            r1 = local_rows(l1, BLOCK, 1, N, S)
            for i in range(S):
                row_i = (k1 if c0[i] else k0) + r0[i] + first
                for j in range(S):
                    kick = scaled(row(kicks, row_i + r1[j], 2), w0[i] * w1[j], 2)
                    kp = axpy(kp, 1.0, kick, 2)
                    kl = (kl[0], kl[1], kl[2] + d0[i] * kick[1] - d1[j] * kick[0])
            m = np.float64(mass[p])
            xp = (np.float64(x[p, 0]), np.float64(x[p, 1]), 0.0)
            about_origin = axpy(kl, 1.0, cross(xp, (kp[0], kp[1], 0.0)), 3)
            for a in range(2):
                impulse[k, a] = m * kp[a]
            moment[k, 0] = m * about_origin[2]

    return gather

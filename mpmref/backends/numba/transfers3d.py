r"""The transfer kernels of the Numba backend in 3D: those of :mod:`.transfers2d` (P2G, G2P and the kick gather,
with the same arguments and the same equations) over the :math:`S^3` stencil.

The nodes are rows of the sparse grid (:mod:`.sparse`): per particle, the first rows of its owner block and of
its upper neighbours along axes 0 and 1 (:func:`~.sparse.block_rows_3d`; the one along the last axis is the
next slot), and per axis which of them each stencil node falls in (:func:`~.sparse.hops`) and its row offset
inside (:func:`~.sparse.local_rows`).
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
from .sparse import block_rows_3d, hops, local_rows
from .stencil import axis_stencil, offsets, scaled
from .tuple_math import add_outer, axpy, cross, matrix, row, scaled_row, zeros, zeros2
from .twin import parallel_kernel

#: the law by which P2G computes the stress where it does: each kernel reads its own (:func:`.materials.bound`)
law_stress = None


@lru_cache(maxsize=None)
def p2g_kernel(KERNEL, S, AFFINE, POLY, MLS_FORCE, BLOCK, STRESS_LAW, FUSED=False):
    r"""P2G kernel in 3D: node mass, momentum and internal force (Hu et al. 2018 Eq. 18), as the 2D
    :func:`~.transfers2d.p2g_kernel` (same arguments, same per-particle and per-node arithmetic) over the
    :math:`S^3` nodes of each particle's stencil, in the order ``(i, j, l)`` of the axes.

    Docs: docs/performance.md#the-fused-p2g
    """
    SOURCES = SOURCE_DIGEST
    N = BLOCK**3  # nodes (rows) per block

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
                fluid_tau = np.empty((3, 3), grid.dtype)  # one allocation per group
                work = np.empty((WORK if FLUIDS_ONLY else 0, 3, 3), grid.dtype)
                folded = np.empty((3, 3), grid.dtype)
                q = np.empty((3 if POLY else 0, S, S))
                qnorm = np.empty((3 if POLY else 0, S))
                w_arr = np.empty((3 if POLY else 0, S))
                fx_arr = np.empty(3 if POLY else 0)
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
                    Q = matrix(tau, real(scale), 3)
                    mv = scaled_row(v, p, m, 3)
                    if FUSED and MLS_FORCE:  # the stress joins the affine matrix once: A_p = m_p C_p + dt Q_p
                        for a in range(3):
                            for b in range(3):
                                folded[a, b] = (m * C[p, a, b] if AFFINE else 0.0) + real(dt) * Q[a][b]
                        mC = matrix(folded, real(1.0), 3)
                    elif AFFINE:
                        mC = matrix(C[p], m, 3)
                    else:
                        mC = Q  # unused
                    b0, f0, w0, d0, g0, wt0 = axis_stencil(KERNEL, x[p, 0], origin[0], dx, inv_dx, real, S)
                    b1, f1, w1, d1, g1, wt1 = axis_stencil(KERNEL, x[p, 1], origin[1], dx, inv_dx, real, S)
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
                        for a in range(3):
                            axis_basis(w_arr[a], fx_arr[a], dx, q[a], qnorm[a])
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

    return parallel_kernel(
        bound(p2g, law_stress=functions(STRESS_LAW).stress if FLUIDS_ONLY else None), cache=True)


@lru_cache(maxsize=None)
def g2p_kernel(KERNEL, S, AFFINE, POLY, FLIP, MLS_GRADIENT, BLOCK):
    r"""G2P kernel in 3D: PIC velocity, affine matrix, PolyPIC modes, FLIP blend, F or J and position (Jiang et
    al. 2015 §5; Hu et al. 2018 §4), as the 2D :func:`~.transfers2d.g2p_kernel` (same arguments, same sums and
    per-particle update) over the :math:`S^3` nodes of each particle's stencil."""
    NEED_B = AFFINE or MLS_GRADIENT
    SOURCES = SOURCE_DIGEST
    N = BLOCK**3

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
            q = np.empty((3, S, S))
            qnorm = np.empty((3, S))
            w_arr = np.empty((3, S))
            fx_arr = np.empty(3)
            acc = np.empty((max(n_modes, 1), 3))
            for k in range(chunk * G2P_CHUNK, min(n, (chunk + 1) * G2P_CHUNK)):
                p = rows[k] if some else np.int64(k)
                if POLY:
                    acc[:] = 0.0
                v_pic, dv_flip = zeros(real, 3), zeros(real, 3)
                B, grad_v = zeros2(real, 3), zeros2(real, 3)
                b0, f0, w0, d0, g0, wt0 = axis_stencil(KERNEL, x[p, 0], origin[0], dx, inv_dx, real, S)
                b1, f1, w1, d1, g1, wt1 = axis_stencil(KERNEL, x[p, 1], origin[1], dx, inv_dx, real, S)
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
                    for a in range(3):
                        axis_basis(w_arr[a], fx_arr[a], dx, q[a], qnorm[a])
                for i in range(S):
                    ka, kb = (k10, k11) if c0[i] else (k00, k01)
                    for j in range(S):
                        w01 = wt0[i] * wt1[j]
                        row_ij = (kb if c1[j] else ka) + r0[i] + r1[j]
                        for l in range(S):
                            idx = row_ij + r2[l]
                            w = w01 * wt2[l]
                            vi = row(v_grid, idx, 3)
                            v_pic = axpy(v_pic, w, vi, 3)
                            if NEED_B:
                                B = add_outer(B, scaled(vi, w, 3), (d0[i], d1[j], d2[l]), 3)
                            if not MLS_GRADIENT:
                                g = (g0[i] * wt1[j] * wt2[l], g1[j] * wt0[i] * wt2[l], g2[l] * w01)
                                grad_v = add_outer(grad_v, vi, g, 3)
                            if FLIP:
                                dv_flip = axpy(dv_flip, -w, row(v_tilde, idx, 3), 3)
                            if POLY:
                                gather_modes(acc, idx, w, (i, j, l), v_grid, q, mode_index)
                move_particle(p, x, v, dt, inertia, flip_alpha, v_pic, dv_flip, B, acc, qnorm, mode_index, x_new,
                              v_new, C_new, modes_new, AFFINE, POLY, FLIP)
                deform_particle(p, 3, F, J, dt, inertia, B, grad_v, F_new, J_new, MLS_GRADIENT, F_new.shape[0] > 0,
                                J_new.shape[0] > 0)

    return g2p


@lru_cache(maxsize=None)
def kick_gather_kernel(KERNEL, S, BLOCK):
    r"""The kick gather of conservative level interfaces in 3D, as the 2D :func:`~.transfers2d.kick_gather_kernel`
    (same arguments, the same skipping of particles whose stencil reaches no kick): each particle's impulse
    :math:`\delta P_p = m_p \sum_i w_{ip} k_i` and its moment about the origin
    :math:`\delta L_p = m_p (x_p \times \sum_i w_{ip} k_i + \sum_i w_{ip} (x_i - x_p) \times k_i)`, three columns.

    Docs: docs/async.md#conservative-interfaces
    """
    SOURCES = SOURCE_DIGEST
    N = BLOCK**3

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
            b2, f2, w2, _ = kernel_axis(KERNEL, np.float64, (x[p, 2] - origin[2]) / dx)
            k00, k01, k10, k11 = block_rows_3d(b0, b1, b2, slot_of, table_strides, BLOCK)
            reached = False  # whether a block the stencil reaches (these four and the next along z) has a kick
            for start in (k00, k01, k10, k11):
                s_ = (first + start) // N
                reached = reached or kicked[s_] or kicked[s_ + 1]
            if not reached:
                continue  # no kick there: the impulse and moment stay zero
            kp, kl = zeros(np.float64, 3), zeros(np.float64, 3)
            d0, d1 = offsets(f0, dx, S), offsets(f1, dx, S)
            d2 = offsets(f2, dx, S)
            l0, l1, l2 = b0 % BLOCK, b1 % BLOCK, b2 % BLOCK
            c0, c1 = hops(l0, BLOCK, S), hops(l1, BLOCK, S)
            r0, r1 = local_rows(l0, BLOCK, BLOCK * BLOCK, 0, S), local_rows(l1, BLOCK, BLOCK, 0, S)
            r2 = local_rows(l2, BLOCK, 1, N, S)
            for i in range(S):
                ka, kb = (k10, k11) if c0[i] else (k00, k01)
                for j in range(S):
                    row_ij = (kb if c1[j] else ka) + r0[i] + r1[j] + first
                    for l in range(S):
                        kick = scaled(row(kicks, row_ij + r2[l], 3), w0[i] * w1[j] * w2[l], 3)
                        kp = axpy(kp, 1.0, kick, 3)
                        kl = axpy(kl, 1.0, cross((d0[i], d1[j], d2[l]), kick), 3)
            m = np.float64(mass[p])
            xp = (np.float64(x[p, 0]), np.float64(x[p, 1]), np.float64(x[p, 2]))
            about_origin = axpy(kl, 1.0, cross(xp, kp), 3)
            for a in range(3):
                impulse[k, a] = m * kp[a]
                moment[k, a] = m * about_origin[a]

    return gather
